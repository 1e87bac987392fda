"""Analysis plans: a strict YAML language saying which metrics, conditions, groups, tests and figures.

A plan is validated completely before anything runs; every problem is reported with ``file:line:col``,
the key path, what was found and what is allowed, and an unknown or misspelt name gets the nearest valid
one as a suggestion. This module holds the schema and the loading; the checks of names and
cross-references (against the catalogue and the study's protocol) are in
:mod:`studyctl.analysis.plan_checks`. See ``analysis/*.yaml`` for the four reference plans.

Shape (keys marked * are required)::

    version: 1
    study*: bio_inspired_palpation          # the protocol the data must come from
    title*: "..."
    paper: "citation"
    data: {source: database}                # or {source: csv, path: data/counts.csv} (relative to the plan)
    alpha: 0.05
    missing: available                      # available | complete_cases | fail
    aggregate: mean                         # repetitions → one value per participant × condition: mean | median | none
    conditions*: [none, {id: linear, label: Linear}, ...]
    groups: [novice, expert]
    metrics*:
      accuracy: {metric: localisation_accuracy, params: {tolerance_cells: 1}, label: ..., unit: ...}
    tests*:
      - id: groups
        test: rank_sum
        metrics: [accuracy]
        compare: group                      # condition | group | the metrics' level (tumour_class, nodule, item)
        by: [condition]                     # one test per level of these factors
        levels: [...]                       # subset/order of the compared levels
        pairs: all                          # two-level tests over more levels: all pairs, or a list of pairs
        reference: BL                       # percent_change: the reference level
        posthoc: {test: dunn, p_adjust: holm, when: significant}
        correction: none                    # p adjustment across this entry's rows
        options: {alternative: two-sided}
        effect_size: [rank_biserial]
        role: paper                         # paper | within_subject | supplementary
        published: {p: 0.071}               # the paper's numbers, printed beside ours
    figures:
      - {id: fig8, kind: box, metrics: [force], by: [condition, group], marks: conditions}
"""

from __future__ import annotations

import types
import typing
from pathlib import Path
from typing import Annotated, Any, Literal, Union

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from studyctl import yamlmarks
from studyctl.analysis.metric_defs import BUILTIN
from studyctl.analysis.plan_checks import check_names, dotted
from studyctl.errors import ProtocolError, ValueTypeError
from studyctl.inputs import read_text
from studyctl.problems import Problem
from studyctl.suggest import did_you_mean, named
from studyctl.yamlmarks import MarkedData

ROLES = ("paper", "within_subject", "supplementary")
MISSING = ("available", "complete_cases", "fail")
AGGREGATE = ("mean", "median", "none")


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Level(_Strict):
    """A condition or group level: its id and a display label."""

    id: str
    label: str | None = None

    @property
    def display(self) -> str:
        return self.label or self.id


class DataSource(_Strict):
    """Where the plan's data come from."""

    source: Literal["database", "csv"] = "database"
    path: str | None = None


class MetricSpec(_Strict):
    """One metric the plan uses: a built-in (``metric``) or a CSV metric name, with overrides."""

    metric: str | None = None
    label: str | None = None
    unit: str | None = None
    kind: Literal["continuous", "proportion", "ordinal"] | None = None
    level: str | None = None
    params: dict[str, float | int | str] = Field(default_factory=dict)
    description: str | None = None


class Posthoc(_Strict):
    """Pairwise follow-up of an omnibus test."""

    test: str
    p_adjust: Literal["none", "holm", "bonferroni", "bh"] = "holm"
    when: Literal["significant", "always"] = "significant"
    variant: Literal["dunn", "multcompare"] | None = None


class PlanTest(_Strict):
    """One family of tests (one row per metric × split level × pair)."""

    id: str
    test: str
    metrics: list[str]
    compare: str = "condition"
    by: list[str] = Field(default_factory=list)
    levels: list[str] | None = None
    pairs: Literal["all"] | list[list[str]] | None = None
    reference: str | None = None
    posthoc: Posthoc | None = None
    correction: Literal["none", "holm", "bonferroni", "bh"] = "none"
    options: dict[str, str | float | int | bool] = Field(default_factory=dict)
    effect_size: list[str] | None = None
    alpha: float | None = None
    role: Literal["paper", "within_subject", "supplementary"] = "paper"
    title: str | None = None
    description: str | None = None
    published: dict[str, float | int | str] | None = None

    @field_validator("alpha")
    @classmethod
    def _alpha_range(cls, v: float | None) -> float | None:
        if v is not None and not 0 < v < 1:
            raise ValueError(f"alpha must be between 0 and 1 (exclusive), found {v}")
        return v


class FigureEntry(_Strict):
    """One figure: kind, what it shows, and which test supplies significance marks."""

    id: str
    kind: str
    metrics: list[str] = Field(default_factory=list)
    by: list[str] = Field(default_factory=list)
    marks: str | None = None
    title: str | None = None
    caption: str | None = None
    options: dict[str, Any] = Field(default_factory=dict)


class AnalysisPlan(_Strict):
    """A validated analysis plan (load it with :func:`load_plan`)."""

    version: Literal[1] = 1
    study: str
    title: str
    paper: str | None = None
    description: str | None = None
    data: DataSource = DataSource()
    alpha: float = 0.05
    missing: Literal["available", "complete_cases", "fail"] = "available"
    aggregate: Literal["mean", "median", "none"] = "mean"
    conditions: list[Annotated[Union[str, Level], Field(union_mode="left_to_right")]]  # noqa: UP007
    groups: list[Annotated[Union[str, Level], Field(union_mode="left_to_right")]] = Field(  # noqa: UP007
        default_factory=list
    )
    metrics: dict[str, MetricSpec]
    tests: list[PlanTest]
    figures: list[FigureEntry] = Field(default_factory=list)
    # Filled by load_plan, not by the YAML.
    source_path: str | None = Field(default=None, exclude=True)

    @field_validator("alpha")
    @classmethod
    def _alpha_range(cls, v: float) -> float:
        if not 0 < v < 1:
            raise ValueError(f"alpha must be between 0 and 1 (exclusive), found {v}")
        return v

    # -- convenience -----------------------------------------------------------------------------
    @property
    def condition_levels(self) -> list[Level]:
        return [c if isinstance(c, Level) else Level(id=c) for c in self.conditions]

    @property
    def group_levels(self) -> list[Level]:
        return [g if isinstance(g, Level) else Level(id=g) for g in self.groups]

    @property
    def condition_ids(self) -> list[str]:
        return [c.id for c in self.condition_levels]

    @property
    def group_ids(self) -> list[str]:
        return [g.id for g in self.group_levels]

    def metric_name(self, metric_id: str) -> str:
        """The built-in (or CSV) metric behind plan metric ``metric_id``."""
        return self.metrics[metric_id].metric or metric_id

    def metric_kind(self, metric_id: str) -> str:
        spec = self.metrics[metric_id]
        if spec.kind:
            return spec.kind
        builtin = BUILTIN.get(self.metric_name(metric_id))
        return builtin.kind if builtin else "continuous"

    def metric_level(self, metric_id: str) -> str | None:
        spec = self.metrics[metric_id]
        if spec.level:
            return spec.level
        builtin = BUILTIN.get(self.metric_name(metric_id))
        return builtin.level if builtin else None

    def metric_label(self, metric_id: str) -> str:
        spec = self.metrics[metric_id]
        builtin = BUILTIN.get(self.metric_name(metric_id))
        return spec.label or (builtin.label if builtin else metric_id)

    def metric_unit(self, metric_id: str) -> str:
        spec = self.metrics[metric_id]
        if spec.unit is not None:
            return spec.unit
        builtin = BUILTIN.get(self.metric_name(metric_id))
        return builtin.unit if builtin else ""

    def metric_minimum(self, metric_id: str) -> float | None:
        """The least value plan metric ``metric_id`` can take by its built-in definition (None: unbounded or
        not a built-in metric)."""
        builtin = BUILTIN.get(self.metric_name(metric_id))
        return builtin.minimum if builtin else None

    def metric_params(self, metric_id: str) -> dict[str, float | int | str]:
        builtin = BUILTIN.get(self.metric_name(metric_id))
        return {**(dict(builtin.params) if builtin else {}), **self.metrics[metric_id].params}

    def test(self, test_id: str) -> PlanTest:
        return named(self.tests, test_id, what="test", plural="tests", where=" in the plan")

    def level_order(self, factor: str, entry: PlanTest) -> list[str] | None:
        """The order in which ``entry`` lists the levels of ``factor``: the entry's own ``levels`` for the factor
        it compares, else the plan's conditions or groups; None (order of appearance in the data) for any other
        factor. The runner and everything that reads its rows back (model coefficients) order levels by it."""
        if factor == entry.compare and entry.levels:
            return list(entry.levels)
        if factor == "condition":
            return self.condition_ids
        if factor == "group":
            return self.group_ids or None
        return None

    def csv_path(self) -> Path | None:
        """The CSV data file, resolved against the plan's folder."""
        if self.data.source != "csv" or self.data.path is None:
            return None
        p = Path(self.data.path)
        if not p.is_absolute() and self.source_path:
            p = Path(self.source_path).parent / p
        return p


# ---------------------------------------------------------------------------------------------------
# Unknown-key detection with suggestions (before pydantic, so messages are ours)


def _models_in(annotation: Any) -> list[tuple[str, type[BaseModel]]]:
    """(container, model) pairs reachable from a field annotation: '' direct, 'list', 'dict'."""
    found: list[tuple[str, type[BaseModel]]] = []
    origin = typing.get_origin(annotation)
    args = typing.get_args(annotation)
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        found.append(("", annotation))
    elif origin is Annotated:
        found.extend(_models_in(args[0]))
    elif origin in (Union, types.UnionType):
        for a in args:
            found.extend(_models_in(a))
    elif origin is list:
        found.extend(("list", m) for c, m in _models_in(args[0]) if c == "")
    elif origin is dict:
        found.extend(("dict", m) for c, m in _models_in(args[1]) if c == "")
    return found


def _public_fields(model: type[BaseModel]) -> list[str]:
    return [name for name, f in model.model_fields.items() if not f.exclude]


def _unknown_keys(data: Any, model: type[BaseModel], path: tuple, doc: MarkedData, problems: list[str]) -> None:
    if not isinstance(data, dict):
        return
    allowed = _public_fields(model)
    for key, value in data.items():
        if key not in model.model_fields or model.model_fields[key].exclude:
            problems.append(
                f"{doc.where((*path, key))}: {dotted((*path, key))}: unknown key {key!r}{did_you_mean(key, allowed)}"
                f" (allowed here: {', '.join(allowed)})"
            )
            continue
        for container, sub in _models_in(model.model_fields[key].annotation):
            if container == "" and isinstance(value, dict):
                _unknown_keys(value, sub, (*path, key), doc, problems)
            elif container == "list" and isinstance(value, list):
                for i, item in enumerate(value):
                    if isinstance(item, dict):
                        _unknown_keys(item, sub, (*path, key, i), doc, problems)
            elif container == "dict" and isinstance(value, dict):
                for k, item in value.items():
                    if isinstance(item, dict):
                        _unknown_keys(item, sub, (*path, key, k), doc, problems)


def _pydantic_problems(exc: ValidationError, doc: MarkedData) -> list[str]:
    problems = []
    seen: set[tuple] = set()
    for err in exc.errors():
        loc = tuple(err["loc"])
        # Union members add their type name to the location ("str", "Level"); drop those parts.
        clean = tuple(p for p in loc if not (isinstance(p, str) and (p in ("str", "Level") or "[" in p)))
        if err["type"] == "extra_forbidden":
            continue  # reported by _unknown_keys with a suggestion
        if clean in seen:
            continue
        seen.add(clean)
        found = err.get("input")
        msg = err["msg"]
        if err["type"] == "missing":
            problems.append(f"{doc.where(clean)}: {dotted(clean)}: required key is missing")
            continue
        if err["type"] == "literal_error" and isinstance(found, str):
            expected = err.get("ctx", {}).get("expected", "")
            options = [o.strip(" '") for o in expected.replace(" or ", ",").split(",") if o.strip()]
            msg = f"{msg}{did_you_mean(found, options)}"
        if isinstance(msg, str) and msg.startswith("Value error, "):
            msg = msg[len("Value error, ") :]
        shown = found if not isinstance(found, dict | list) else type(found).__name__
        problems.append(f"{doc.where(clean)}: {dotted(clean)}: {msg} (found {shown!r})")
    return problems


def _line_key(text: str, source: str) -> tuple[int, int]:
    """Sort key of a problem line: its (line, column) after ``source:`` (problems without one go last)."""
    rest = text[len(source) + 1 :] if text.startswith(source + ":") else ""
    parts = rest.split(":", 2)
    try:
        return int(parts[0]), int(parts[1])
    except (ValueError, IndexError):
        return 10**9, 0


def parse_plan(doc: MarkedData) -> AnalysisPlan:
    """Validate a located YAML document as an analysis plan; raise with every problem found."""
    if not isinstance(doc.data, dict):
        raise ProtocolError(f"{doc.source}:1:1: an analysis plan is a YAML mapping, found {type(doc.data).__name__}")
    problems: list[str] = []
    _unknown_keys(doc.data, AnalysisPlan, (), doc, problems)
    data = {k: v for k, v in doc.data.items() if k in _public_fields(AnalysisPlan)}
    data["source_path"] = doc.source
    plan: AnalysisPlan | None = None
    try:
        plan = AnalysisPlan.model_validate(_prune_unknown(data, AnalysisPlan))
    except ValidationError as exc:
        problems.extend(_pydantic_problems(exc, doc))
    if plan is not None:
        problems.extend(check_names(plan, doc))
    if problems:
        problems.sort(key=lambda text: _line_key(text, doc.source))
        head = f"{doc.source}: {len(problems)} problem(s) in the analysis plan"
        raise ProtocolError(head + ":\n  " + "\n  ".join(problems), problems)
    if plan is None:  # unreachable: a failed validation always leaves problems
        raise ProtocolError(f"{doc.source}: the analysis plan is invalid")
    return plan


def _prune_unknown(data: Any, model: type[BaseModel]) -> Any:
    """Drop unknown keys (already reported) so pydantic reports only type problems."""
    if not isinstance(data, dict):
        return data
    out = {}
    for key, value in data.items():
        if key not in model.model_fields:
            continue
        subs = _models_in(model.model_fields[key].annotation)
        for container, sub in subs:
            if container == "" and isinstance(value, dict):
                value = _prune_unknown(value, sub)
            elif container == "list" and isinstance(value, list):
                value = [_prune_unknown(v, sub) if isinstance(v, dict) else v for v in value]
            elif container == "dict" and isinstance(value, dict):
                value = {k: _prune_unknown(v, sub) if isinstance(v, dict) else v for k, v in value.items()}
        out[key] = value
    return out


def load_plan(path_or_name: str | Path) -> AnalysisPlan:
    """Load and validate an analysis plan from a file, or a shipped plan by name.

    Parameters
    ----------
    path_or_name
        A YAML file, or the name of a shipped plan (``bio_inspired_palpation``, ``needle_insertion``,
        ``data_driven_palpation``, ``pseudo_haptic_palpation``).

    Raises
    ------
    ProtocolError
        With ``problems`` listing every error as ``file:line:col: key.path: message``.
    NotFoundError
        When neither a file nor a shipped plan of that name exists.
    """
    from studyctl.resources import find_shipped

    path = find_shipped("analysis", path_or_name)
    return parse_plan(load_plan_yaml(path))


def require_loaded(plan: object, where: str) -> AnalysisPlan:
    """``plan`` itself, or a one-line error for a caller who passed a plan's name or path (the old API)."""
    if isinstance(plan, AnalysisPlan):
        return plan
    raise ValueTypeError(
        f"{where} takes a loaded plan, got {type(plan).__name__} {plan!r}; "
        f"load it first: {where}(load_plan({plan!r}), ...)"
    )


def load_plan_yaml(path: Path | str) -> MarkedData:
    """Parse a plan file keeping positions; keys are read as text, merge keys refused.

    Raises
    ------
    ProtocolError
        On an unreadable or empty file, a syntax error (with line and column), or duplicate, merge or
        non-name keys.
    """
    source = str(path)
    if not Path(path).exists():
        raise ProtocolError(f"{source}: no such file")
    text = read_text(path, "analysis plan", error=ProtocolError)
    doc = yamlmarks.load_marked(text, source, merge_keys=False, text_keys=True)
    syntax = [p for p in doc.problems if p.kind in (yamlmarks.SYNTAX, yamlmarks.TOO_BIG)]
    if syntax:
        p = syntax[0]
        if p.kind == yamlmarks.TOO_BIG:
            raise ProtocolError(f"{source}:{p.mark.line}:{p.mark.column}: {p.what}: {p.found}; allowed {p.allowed}")
        detail = p.what if p.what.startswith("YAML syntax error") else f"YAML syntax error: {p.found}"
        raise ProtocolError(f"{source}:{p.mark.line}:{p.mark.column}: {detail}")
    if doc.data is None and not doc.values:
        raise ProtocolError(f"{source}: the file is empty; an analysis plan is a YAML mapping")
    if doc.problems:
        problems = [_yaml_problem(p, doc) for p in doc.problems]
        raise ProtocolError(f"{source}: {len(problems)} problem(s):\n  " + "\n  ".join(problems), problems)
    return doc


def _yaml_problem(p: Problem, doc: MarkedData) -> str:
    """A loading problem in the plan's wording."""
    where = f"{p.file}:{p.mark.line}:{p.mark.column}"
    if p.kind == yamlmarks.DUPLICATE_KEY:
        return (
            f"{where}: {dotted(p.path)}: duplicate key {p.path[-1]!r} (the first is on line "
            f"{doc.keys[p.path].line}); remove one of them"
        )
    if p.kind == yamlmarks.MERGE_KEY:
        return f"{p.file}:{p.mark.line}: YAML merge keys (<<) are not supported"
    if p.kind == yamlmarks.BAD_KEY:
        return f"{where}: mapping keys must be plain names, found {p.found}"
    return f"{where}: {dotted(p.path)}: {p.what}: found {p.found}, allowed {p.allowed}"


def check_plan(path_or_name: str | Path) -> list[str]:
    """Every problem of a plan (empty when it is valid)."""
    try:
        load_plan(path_or_name)
    except ProtocolError as exc:
        return exc.problems
    return []
