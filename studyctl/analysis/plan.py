"""Analysis plans: a strict YAML language saying which metrics, conditions, groups, tests and figures.

A plan is validated completely before anything runs; every problem is reported with ``file:line:col``,
the key path, what was found and what is allowed, and an unknown or misspelt name gets the nearest valid
one as a suggestion. See ``analysis/*.yaml`` for the four reference plans.

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

from studyctl.analysis import catalog
from studyctl.analysis.metric_defs import BUILTIN, KINDS
from studyctl.errors import ProtocolError
from studyctl.protocol import yamlmarks
from studyctl.protocol.problems import Problem, format_path
from studyctl.protocol.yamlmarks import MarkedData
from studyctl.suggest import did_you_mean

FIGURE_KINDS = tuple(catalog.FIGURE_KINDS)  # listed, with where their data come from, in the catalogue
ROLES = ("paper", "within_subject", "supplementary")
MISSING = ("available", "complete_cases", "fail")
AGGREGATE = ("mean", "median", "none")
FIXED_FACTORS = ("condition", "group")


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

    def metric_params(self, metric_id: str) -> dict[str, float | int | str]:
        builtin = BUILTIN.get(self.metric_name(metric_id))
        return {**(dict(builtin.params) if builtin else {}), **self.metrics[metric_id].params}

    def test(self, test_id: str) -> PlanTest:
        for t in self.tests:
            if t.id == test_id:
                return t
        raise KeyError(test_id)

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


# ---------------------------------------------------------------------------------------------------
# Cross-reference checks


def _check_names(plan: AnalysisPlan, doc: MarkedData) -> list[str]:
    problems: list[str] = []

    def bad(path: tuple, text: str) -> None:
        problems.append(f"{doc.where(path)}: {dotted(path)}: {text}")

    def dupes(ids: list[str], section: str) -> None:
        seen: set[str] = set()
        for i, v in enumerate(ids):
            if v in seen:
                bad((section, i), f"duplicate id {v!r}; ids must be unique")
            seen.add(v)

    dupes(plan.condition_ids, "conditions")
    dupes(plan.group_ids, "groups")
    dupes([t.id for t in plan.tests], "tests")
    dupes([f.id for f in plan.figures], "figures")
    if not plan.conditions:
        bad(("conditions",), "at least one condition is required")

    csv_source = plan.data.source == "csv"
    if csv_source and not plan.data.path:
        bad(("data",), "source 'csv' needs a path (relative to the plan file)")
    if not csv_source and plan.data.path:
        bad(("data", "path"), "a path is only used with source 'csv'")
    if csv_source and plan.data.path:
        p = plan.csv_path()
        if p is not None and not p.is_file():
            bad(("data", "path"), f"no such file {str(p)!r}")

    for mid, spec in plan.metrics.items():
        name = spec.metric or mid
        if not csv_source and name not in BUILTIN:
            key = ("metrics", mid, "metric") if spec.metric else ("metrics", mid)
            bad(key, f"unknown metric {name!r}{did_you_mean(name, BUILTIN)} (built-in metrics: {', '.join(BUILTIN)})")
            continue
        if spec.kind is not None and spec.kind not in KINDS:
            bad(("metrics", mid, "kind"), f"unknown kind {spec.kind!r}")
        builtin = BUILTIN.get(name)
        if builtin is not None:
            for p in spec.params:
                if p not in builtin.params:
                    allowed = ", ".join(builtin.params) or "none"
                    bad(
                        ("metrics", mid, "params", p),
                        f"{name} has no parameter {p!r}{did_you_mean(p, builtin.params)} (its parameters: {allowed})",
                    )

    problems.extend(_check_against_protocol(plan, doc))
    metric_ids = list(plan.metrics)
    test_ids = [t.id for t in plan.tests]
    conditions = plan.condition_ids
    groups = plan.group_ids

    for i, t in enumerate(plan.tests):
        name = catalog.ALIASES.get(t.test, t.test)
        spec = catalog.TESTS.get(name)
        if spec is None:
            known = sorted(set(catalog.TESTS) | set(catalog.ALIASES))
            bad(
                ("tests", i, "test"),
                f"unknown test {t.test!r}{did_you_mean(t.test, known)}"
                f" (known tests: {', '.join(sorted(catalog.TESTS))})",
            )
            continue
        if not t.metrics:
            bad(("tests", i, "metrics"), "name at least one metric")
        levels_of_metrics: set[str | None] = set()
        for j, m in enumerate(t.metrics):
            if m not in plan.metrics:
                bad(
                    ("tests", i, "metrics", j),
                    f"unknown metric {m!r}{did_you_mean(m, metric_ids)} (this plan's metrics: {', '.join(metric_ids)})",
                )
                continue
            levels_of_metrics.add(plan.metric_level(m))
            kind = plan.metric_kind(m)
            if spec.design == catalog.PROPORTION and kind != "proportion":
                bad(("tests", i, "metrics", j), f"{t.test} needs a proportion metric; {m!r} is {kind}")
            if name == "likert_table" and kind != "ordinal":
                bad(("tests", i, "metrics", j), f"likert_table needs an ordinal (Likert) metric; {m!r} is {kind}")
        factors = list(FIXED_FACTORS) + sorted(x for x in levels_of_metrics if x)
        for key, factor in [("compare", t.compare)] + [("by", b) for b in t.by]:
            path = ("tests", i, key) if key == "compare" else ("tests", i, "by", t.by.index(factor))
            if factor not in factors:
                bad(
                    path,
                    f"unknown factor {factor!r}{did_you_mean(factor, factors)} (factors here: {', '.join(factors)})",
                )
            elif factor not in FIXED_FACTORS and len(levels_of_metrics) > 1:
                bad(path, f"factor {factor!r} is not a level of every metric in this test; split the test")
        if t.compare in t.by:
            bad(("tests", i, "by"), f"{t.compare!r} is both compared and split by; drop it from 'by'")
        if t.compare == "group" and not groups:
            bad(("tests", i, "compare"), "compares groups but the plan declares no 'groups'")
        if spec.design == catalog.WITHIN and t.compare == "group":
            bad(
                ("tests", i, "compare"),
                f"{name} pairs values by participant, so it cannot compare groups (each participant is in one group)",
            )
        known_levels = {"condition": conditions, "group": groups}.get(t.compare)
        for j, lv in enumerate(t.levels or []):
            if known_levels is not None and lv not in known_levels:
                bad(
                    ("tests", i, "levels", j),
                    f"unknown {t.compare} {lv!r}{did_you_mean(lv, known_levels)} (allowed: {', '.join(known_levels)})",
                )
        if t.levels is not None and len(t.levels) < spec.min_levels:
            bad(("tests", i, "levels"), f"{name} needs at least {spec.min_levels} levels, found {len(t.levels)}")
        if isinstance(t.pairs, list):
            if spec.max_levels != 2:
                bad(("tests", i, "pairs"), f"{name} compares all levels at once; 'pairs' is for two-level tests")
            for j, pair in enumerate(t.pairs):
                if len(pair) != 2 or pair[0] == pair[1]:
                    bad(("tests", i, "pairs", j), f"a pair names two different levels, found {pair!r}")
                for lv in pair:
                    if known_levels is not None and lv not in known_levels:
                        bad(("tests", i, "pairs", j), f"unknown {t.compare} {lv!r}{did_you_mean(lv, known_levels)}")
        if name == "percent_change":
            if t.reference is None:
                bad(("tests", i), "percent_change needs a 'reference' level (e.g. the baseline condition)")
            elif known_levels is not None and t.reference not in known_levels:
                bad(
                    ("tests", i, "reference"),
                    f"unknown {t.compare} {t.reference!r}"
                    f"{did_you_mean(t.reference, known_levels)} (allowed: {', '.join(known_levels)})",
                )
        elif t.reference is not None:
            bad(("tests", i, "reference"), f"'reference' is only used by percent_change, not {name}")
        for key, value in t.options.items():
            if key not in spec.options:
                allowed = ", ".join(sorted(spec.options)) or "none"
                bad(
                    ("tests", i, "options", key),
                    f"{name} has no option {key!r}{did_you_mean(key, spec.options)} (its options: {allowed})",
                )
                continue
            values = catalog.OPTION_VALUES.get(key)
            if values is not None and value not in values:
                bad(
                    ("tests", i, "options", key),
                    f"{key} must be one of {', '.join(map(str, values))}, "
                    f"found {value!r}{did_you_mean(str(value), map(str, values))}",
                )
            if key == "confidence" and not (isinstance(value, float | int) and 0 < value < 1):
                bad(("tests", i, "options", key), f"confidence must be in (0, 1), found {value!r}")
        if t.posthoc is not None:
            if not spec.posthoc:
                bad(("tests", i, "posthoc"), f"{name} has no post-hoc procedure")
            elif t.posthoc.test not in spec.posthoc:
                bad(
                    ("tests", i, "posthoc", "test"),
                    f"unknown post-hoc {t.posthoc.test!r} for {name}"
                    f"{did_you_mean(t.posthoc.test, spec.posthoc)} (allowed: {', '.join(sorted(spec.posthoc))})",
                )
        for j, es in enumerate(t.effect_size or []):
            if es not in spec.effect_sizes:
                bad(
                    ("tests", i, "effect_size", j),
                    f"{name} reports no effect size {es!r}"
                    f"{did_you_mean(es, spec.effect_sizes)} (available: {', '.join(spec.effect_sizes) or 'none'})",
                )

    for i, f in enumerate(plan.figures):
        if f.kind not in FIGURE_KINDS:
            bad(
                ("figures", i, "kind"),
                f"unknown figure kind {f.kind!r}{did_you_mean(f.kind, FIGURE_KINDS)}"
                f" (kinds: {', '.join(FIGURE_KINDS)})",
            )
        for j, m in enumerate(f.metrics):
            if m not in plan.metrics:
                bad(("figures", i, "metrics", j), f"unknown metric {m!r}{did_you_mean(m, metric_ids)}")
        if f.marks is not None and f.marks not in test_ids:
            bad(
                ("figures", i, "marks"),
                f"unknown test id {f.marks!r}{did_you_mean(f.marks, test_ids)}"
                f" (this plan's tests: {', '.join(test_ids)})",
            )
        factors = list(FIXED_FACTORS) + sorted({plan.metric_level(m) for m in f.metrics if m in plan.metrics} - {None})
        for j, b in enumerate(f.by):
            if b not in factors:
                bad(
                    ("figures", i, "by", j),
                    f"unknown factor {b!r}{did_you_mean(b, factors)} (factors: {', '.join(factors)})",
                )
        if f.kind in ("box", "proportion", "percent_change", "likert") and not f.metrics:
            bad(("figures", i, "metrics"), f"a {f.kind} figure needs at least one metric")
    return problems


def shipped_protocol(name: str):  # -> Protocol | None
    """The shipped protocol called ``name``, or None when there is none (a study of one's own)."""
    from studyctl.errors import NotFoundError
    from studyctl.protocol import load_protocol
    from studyctl.resources import resource_dir

    path = resource_dir("protocols") / f"{name}.yaml"
    if not path.is_file():
        return None
    try:
        return load_protocol(path)
    except (ProtocolError, NotFoundError):
        return None


def _check_against_protocol(plan: AnalysisPlan, doc: MarkedData) -> list[str]:
    """Conditions and groups must exist in the study's protocol (when it is a shipped one)."""
    protocol = shipped_protocol(plan.study)
    if protocol is None:
        return []
    problems = []
    known = list(protocol.condition_ids)
    for i, c in enumerate(plan.condition_ids):
        if c not in known:
            problems.append(
                f"{doc.where(('conditions', i))}: conditions[{i}]: protocol {plan.study!r} has no "
                f"condition {c!r}{did_you_mean(c, known)} (its conditions: {', '.join(known)})"
            )
    strata = list(protocol.stratum_ids)
    for i, g in enumerate(plan.group_ids):
        if g not in strata:
            problems.append(
                f"{doc.where(('groups', i))}: groups[{i}]: protocol {plan.study!r} has no group "
                f"(stratum) {g!r}{did_you_mean(g, strata)} (its strata: {', '.join(strata)})"
            )
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
        problems.extend(_check_names(plan, doc))
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


def dotted(path: tuple) -> str:
    """Render a key path as ``tests[2].posthoc.test`` (the protocol's rendering; plans say "(top level)")."""
    return format_path(path) if path else "(top level)"


def load_plan_yaml(path: Path | str) -> MarkedData:
    """Parse a plan file keeping positions; keys are read as text, merge keys refused.

    Raises
    ------
    ProtocolError
        On an unreadable or empty file, a syntax error (with line and column), or duplicate, merge or
        non-name keys.
    """
    source = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ProtocolError(f"{source}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ProtocolError(f"{source}: cannot read the file ({exc})") from None
    doc = yamlmarks.load_marked(text, source, merge_keys=False, text_keys=True)
    syntax = [p for p in doc.problems if p.kind == yamlmarks.SYNTAX]
    if syntax:
        p = syntax[0]
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
