"""The checks of an analysis plan that look beyond its own schema: names against the catalogue of
metrics, tests and figure kinds, references between its sections, and the conditions and groups of the
study's protocol. Each problem is one line with the plan file's ``line:col`` and the key path.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from studyctl.analysis.metric_defs import BUILTIN, KINDS
from studyctl.errors import NotFoundError, ProtocolError
from studyctl.problems import format_path
from studyctl.suggest import did_you_mean
from studyctl.yamlmarks import MarkedData

if TYPE_CHECKING:
    from studyctl.analysis.plan import AnalysisPlan
    from studyctl.protocol import Protocol

FIXED_FACTORS = ("condition", "group")


def dotted(path: tuple) -> str:
    """Render a key path as ``tests[2].posthoc.test`` (the protocol's rendering; plans say "(top level)")."""
    return format_path(path) if path else "(top level)"


def check_names(plan: AnalysisPlan, doc: MarkedData) -> list[str]:
    """Every name and cross-reference of ``plan``, and its conditions and groups against the protocol."""
    # The catalogue imports the tests (scipy, statsmodels): only once a plan has parsed, so a hostile plan file
    # is refused without them (studyctl.analysis imports lazily for the same reason).
    from studyctl.analysis import catalog  # noqa: PLC0415

    figure_kinds = tuple(catalog.FIGURE_KINDS)  # listed, with where their data come from, in the catalogue
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

    problems.extend(check_against_protocol(plan, doc))
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
        second = t.options.get("factor") if "factor" in spec.options else None
        for key, factor in [("compare", t.compare)] + [("by", b) for b in t.by] + (
            [("factor", second)] if second is not None else []
        ):
            if key == "by":
                path = ("tests", i, "by", t.by.index(factor))
            else:
                path = ("tests", i, key) if key == "compare" else ("tests", i, "options", "factor")
            if factor not in factors:
                bad(
                    path,
                    f"unknown factor {factor!r}{did_you_mean(factor, factors)} (factors here: {', '.join(factors)})",
                )
            elif factor not in FIXED_FACTORS and len(levels_of_metrics) > 1:
                bad(path, f"factor {factor!r} is not a level of every metric in this test; split the test")
        if second is not None and (second == t.compare or second in t.by):
            bad(("tests", i, "options", "factor"), f"the second factor {second!r} is already compared or split by; "
                "name another factor (e.g. group)")
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
        if f.kind not in figure_kinds:
            bad(
                ("figures", i, "kind"),
                f"unknown figure kind {f.kind!r}{did_you_mean(f.kind, figure_kinds)}"
                f" (kinds: {', '.join(figure_kinds)})",
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


def shipped_protocol(name: str) -> Protocol | None:
    """The shipped protocol called ``name``, or None when there is none (a study of one's own)."""
    from studyctl.protocol import load_protocol
    from studyctl.resources import resource_dir

    path = resource_dir("protocols") / f"{name}.yaml"
    if not path.is_file():
        return None
    try:
        return load_protocol(path)
    except (ProtocolError, NotFoundError):
        return None


def check_against_protocol(plan: AnalysisPlan, doc: MarkedData) -> list[str]:
    """Conditions and groups must exist in the study's protocol (when it is a shipped one)."""
    protocol = shipped_protocol(plan.study)
    if protocol is None:
        return []
    problems = []
    names = (
        ("conditions", plan.condition_ids, list(protocol.condition_ids), "condition", "conditions"),
        ("groups", plan.group_ids, list(protocol.stratum_ids), "group (stratum)", "strata"),
    )
    for key, used, known, what, listed in names:
        for i, name in enumerate(used):
            if name not in known:
                problems.append(
                    f"{doc.where((key, i))}: {key}[{i}]: protocol {plan.study!r} has no {what} "
                    f"{name!r}{did_you_mean(name, known)} (its {listed}: {', '.join(known)})"
                )
    return problems
