"""Published targets: a paper's numbers a simulated study is compared with (``format: studyctl-targets/1``).

Each target names a metric of the protocol's analysis plan, optional filters (``where``: condition, group,
level — aliases nodule, tumour, class, item), a statistic, the published value, its uncertainty as printed
(``sd`` and ``n``, ``se``, or a 95 % ``interval``) and a role: ``fit`` targets may be used by
``studyctl calibrate``; ``validation`` targets never are. A ``verdict`` target may carry the published ``p`` of
its test, from which the report says how often a same-size replication would give the paper's verdict at all
(:func:`studyctl.calibration.replication.verdict_replication`). Every mistake is one error with file:line:column,
the field, what is allowed and the nearest valid name.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from studyctl.errors import NotFoundError, PopulationError
from studyctl.suggest import did_you_mean, named

TARGETS_FORMAT = "studyctl-targets/1"
STATISTICS = (
    "mean", "sd", "cv", "median", "iqr", "proportion", "count_total", "pct_change_vs_baseline", "test_p", "verdict",
)
SPREADS = ("sd", "cv")  # between-person spread: judged by the ratio simulated / published (within 1.5×)
#: What a bounded statistic can take (the others are unbounded): a published band is clipped to it, and a
#: replication cannot cross a band edge that lies at it.
_LIMITS = {"proportion": (0.0, 1.0), "sd": (0.0, math.inf), "cv": (0.0, math.inf), "iqr": (0.0, math.inf),
           "count_total": (0.0, math.inf)}
ROLES = ("fit", "validation")
TOP_KEYS = ("format", "protocol", "source", "plan", "alpha", "targets", "note")
TARGET_KEYS = ("id", "metric", "where", "statistic", "value", "p", "uncertainty", "role", "note", "test", "pair",
               "higher", "baseline", "direction_vs", "unit", "headline")
WHERE_KEYS = ("condition", "group", "level")
LEVEL_ALIASES = ("nodule", "tumour", "class", "item")
UNCERTAINTY_KEYS = ("sd", "n", "se", "interval", "basis")
# What a target's uncertainty is (``basis``, required with an interval, se or sd): the paper's own number
# (``paper``: its 95 % CI, SE or SD as printed); recomputed exactly from what it prints (``recomputed``; a
# ``wilson`` score interval from the published count value · n of n, an ``exact_poisson`` (Garwood) interval from
# a published count — both checked against the typed interval); or ``chosen`` by hand (the note says why).
BASES = ("paper", "recomputed", "wilson", "exact_poisson", "chosen")
SPREAD_BASES = ("paper", "recomputed", "chosen")  # for an se or sd
RECOMPUTE_TOLERANCE = 0.006  # a typed recomputed interval may differ from ours by the paper's 2-3 digit rounding
TEST_STATISTICS = ("test_p", "verdict")


def statistic_limits(statistic: str) -> tuple[float, float]:
    """The lowest and highest value ``statistic`` can take."""
    return _LIMITS.get(statistic, (-math.inf, math.inf))


@dataclass(frozen=True)
class Target:
    """One published number (see the module docs). ``value`` is a bool for verdicts."""

    id: str
    metric: str
    statistic: str
    value: Any
    role: str
    where: Mapping[str, str] = field(default_factory=dict)
    uncertainty: Mapping[str, Any] = field(default_factory=dict)
    note: str = ""
    test: str = ""
    pair: tuple[str, ...] = ()  # a test target's two compared levels (a pairwise or post-hoc row), any order
    higher: str = ""  # the level of ``pair`` the paper found higher (its stated direction; '' = none stated)
    baseline: str = ""
    direction_vs: str = ""
    unit: str = "participant"
    headline: bool = True
    location: str = ""  # file:line where it is written
    p: float | None = None  # a verdict's published p-value, when the paper prints one (or it is recomputed)

    def published_p(self) -> float | None:
        """The p-value behind a published verdict: a test_p target's value, a verdict target's ``p``."""
        if self.statistic == "test_p":
            return float(self.value)
        return self.p if self.statistic == "verdict" else None

    def filters(self) -> dict[str, str]:
        """``where`` as metric-table columns (nodule/tumour/class/item → level)."""
        return {("level" if k in LEVEL_ALIASES else k): v for k, v in self.where.items()}

    @property
    def is_test(self) -> bool:
        return self.statistic in TEST_STATISTICS

    def interval(self) -> tuple[float, float] | None:
        """The published band a simulated value should fall in: the printed 95 % interval; else ±1.96 SE when
        an SE is printed; else ±1 SD for a mean or median with a printed SD; else ±1.96 SE derived from n.
        Clipped to what the statistic can take (a proportion in [0, 1], counts and spreads ≥ 0)."""
        band = self._raw_interval()
        if band is None:
            return None
        low, high = statistic_limits(self.statistic)
        return max(band[0], low), min(band[1], high)

    def _raw_interval(self) -> tuple[float, float] | None:
        u, v = self.uncertainty, self.value
        if self.is_test:
            return None
        if "interval" in u:
            lo, hi = u["interval"]
            return float(lo), float(hi)
        if "se" in u:
            return v - 1.96 * float(u["se"]), v + 1.96 * float(u["se"])
        if "sd" in u and self.statistic in ("mean", "median"):
            return v - float(u["sd"]), v + float(u["sd"])
        se = self.published_se()
        return None if se is None else (v - 1.96 * se, v + 1.96 * se)

    def band(self) -> str:
        """What :meth:`interval` is, in words (the report's and agreement.csv's ``band`` column): the paper's
        95 % CI, an interval recomputed from published counts (Wilson, exact Poisson), a CHOSEN band, ±1 SD or
        ±1.96 SE (published, recomputed from the paper, or CHOSEN), or ±1.96 SE derived from n."""
        u = self.uncertainty
        basis = u.get("basis")
        if self.is_test and self.higher:
            lower = self.pair[1] if self.higher == self.pair[0] else self.pair[0]
            return f"verdict and direction ({self.higher} > {lower})"
        if "interval" in u:
            if basis == "wilson":
                n = int(u["n"])
                return f"Wilson 95% from {round(float(self.value) * n)}/{n}"
            if basis == "exact_poisson":
                return f"exact Poisson 95% from {float(self.value):g}"
            return {"chosen": "CHOSEN band", "recomputed": "95% interval recomputed from the paper"}.get(
                str(basis), "paper's 95% CI")
        if self.statistic in SPREADS:
            return "ratio within 1/1.5–1.5"
        if basis == "pilot":  # set by --pilot-db, never written in a file
            return "±1.96 pilot bootstrap SE"
        word = {"chosen": "CHOSEN {}", "recomputed": "{} recomputed from the paper"}.get(str(basis), "published {}")
        if "se" in u:
            return "±1.96 " + word.format("SE")
        if "sd" in u and self.statistic in ("mean", "median"):
            return "±1 " + word.format("SD")
        return "±1.96 SE derived from n" if self.published_se() is not None else ""

    def published_se(self) -> float | None:
        """The standard error of the published number (from what the paper prints), or None."""
        if self.is_test:
            return None
        u = self.uncertainty
        if "se" in u:
            return float(u["se"])
        if "interval" in u:
            lo, hi = u["interval"]
            return (float(hi) - float(lo)) / 3.92
        n = u.get("n")
        if self.statistic in ("mean", "median") and "sd" in u and n:
            return float(u["sd"]) / math.sqrt(float(n)) * (1.2533 if self.statistic == "median" else 1.0)
        if self.statistic in SPREADS and n and n > 1:
            return float(self.value) / math.sqrt(2.0 * (float(n) - 1.0))
        if self.statistic == "proportion" and n:
            p = min(max(float(self.value), 0.5 / float(n)), 1 - 0.5 / float(n))
            return math.sqrt(p * (1 - p) / float(n))
        if self.statistic == "count_total" and float(self.value) >= 0:
            return math.sqrt(max(float(self.value), 1.0))  # Poisson
        return None


@dataclass(frozen=True)
class TargetSet:
    """A checked targets file."""

    protocol: str
    source: str
    targets: tuple[Target, ...]
    alpha: float = 0.05
    plan: str = ""
    path: str = ""
    sha256: str = ""

    def by_role(self, role: str) -> tuple[Target, ...]:
        return tuple(t for t in self.targets if t.role == role)

    def get(self, target_id: str) -> Target:
        return named(self.targets, target_id, what="target", plural="targets")


def load_targets_file(path: str | Path, *, plan: Any | None = None, protocol: Any | None = None) -> TargetSet:
    """Read and check a targets file against the protocol's analysis plan (the plan named in the file, else the
    shipped plan of its protocol) and the protocol's strata."""
    file = Path(path)
    if not file.exists():
        raise NotFoundError(f"targets file {str(path)!r} does not exist; give a studyctl-targets/1 YAML file "
                            "(shipped ones: studyctl/populations/<protocol>.targets.yaml)")
    text = _read_targets_text(file)
    return parse_targets(text, str(file), plan=plan, protocol=protocol,
                         sha256=hashlib.sha256(text.encode("utf-8")).hexdigest())


def _read_targets_text(file: str | Path) -> str:
    """A folder, a binary or an oversized file is one error naming it (read_text), not a traceback."""
    from studyctl.inputs import read_text

    return read_text(file, "targets file (studyctl-targets/1 YAML)", error=PopulationError)


def _marked_targets(text: str, label: str) -> Any:
    """Targets YAML as every reader of it parses it: no merge keys, keys as text, the loader's size, alias and
    depth limits; the first problem is the error."""
    from studyctl.yamlmarks import load_marked

    m = load_marked(text, label, merge_keys=False, text_keys=True)
    if m.problems:
        raise PopulationError(str(m.problems[0]))
    return m


def read_targets_data(path: str | Path) -> Any:
    """The data of a targets file read and parsed as :func:`load_targets_file` does, not yet checked (calibrate
    reads its ``plan:`` with it before the plan, and the statistics it imports, are loaded)."""
    return _marked_targets(_read_targets_text(path), str(path)).data


def _fail(m: Any, label: str, path: tuple[Any, ...], message: str, *, value: bool = True) -> PopulationError:
    mark = m.value_mark(path) if value else m.key_mark(path)
    dotted = ".".join(str(p) for p in path) or "(top)"
    return PopulationError(f"{label}:{mark.line}:{mark.column}: {dotted}: {message}")


def parse_targets(text: str, label: str, *, plan: Any | None = None, protocol: Any | None = None,
                  sha256: str = "") -> TargetSet:
    """Check targets YAML ``text`` (see :func:`load_targets_file`)."""
    m = _marked_targets(text, label)
    data = m.data
    if not isinstance(data, Mapping):
        raise _fail(m, label, (), f"a targets file is a mapping starting with 'format: {TARGETS_FORMAT}'")
    for key in data:
        if key not in TOP_KEYS:
            raise _fail(m, label, (key,), f"unknown key {key!r}{did_you_mean(key, TOP_KEYS)}; allowed: "
                        f"{', '.join(TOP_KEYS)}", value=False)
    if data.get("format") != TARGETS_FORMAT:
        raise _fail(m, label, ("format",), f"format {data.get('format')!r} is not supported; write "
                    f"'format: {TARGETS_FORMAT}'")
    pid = data.get("protocol")
    if not isinstance(pid, str) or not pid:
        raise _fail(m, label, ("protocol",), "protocol must name the protocol (e.g. data_driven_palpation)")
    alpha = data.get("alpha", 0.05)
    if isinstance(alpha, bool) or not isinstance(alpha, int | float) or not 0 < alpha < 1:
        raise _fail(m, label, ("alpha",), f"alpha {alpha!r} must be a number in (0, 1)")
    if plan is None:
        from studyctl.analysis import load_plan

        ref = data.get("plan") or pid
        near = Path(label).parent / str(ref)
        try:
            plan = load_plan(str(near) if near.is_file() else ref)
        except NotFoundError as exc:
            raise _fail(m, label, ("plan",) if "plan" in data else ("protocol",),
                        f"no analysis plan for it ({exc}); name one with plan: FILE") from None
    if protocol is None:
        from studyctl.protocol import load_protocol, resolve_protocol

        try:
            protocol = load_protocol(resolve_protocol(pid))
        except NotFoundError:
            protocol = None
    metrics = list(plan.metrics)
    conditions = list(protocol.condition_ids) if protocol is not None else list(plan.condition_ids)
    groups = list(protocol.stratum_ids) if protocol is not None else list(plan.group_ids)
    tests = {t.id: t for t in plan.tests}
    test_kinds = sorted({t.test for t in plan.tests})
    raw_targets = data.get("targets")
    if not isinstance(raw_targets, list) or not raw_targets:
        raise _fail(m, label, ("targets",), "targets must be a non-empty list of {id, metric, statistic, value, role}")
    out: list[Target] = []
    ids: set[str] = set()
    for i, t in enumerate(raw_targets):
        p = ("targets", i)
        if not isinstance(t, Mapping):
            raise _fail(m, label, p, "a target is a mapping {id, metric, statistic, value, uncertainty, role}")
        for key in t:
            if key not in TARGET_KEYS:
                raise _fail(m, label, (*p, key), f"unknown key {key!r}{did_you_mean(key, TARGET_KEYS)}; allowed: "
                            f"{', '.join(TARGET_KEYS)}", value=False)
        for key in ("id", "metric", "statistic", "value", "role"):
            if key not in t:
                raise _fail(m, label, p, f"missing {key!r}; a target has id, metric, statistic, value, role")
        tid = str(t["id"])
        if tid in ids:
            raise _fail(m, label, (*p, "id"), f"target id {tid!r} is used twice; ids must be unique")
        ids.add(tid)
        if t["metric"] not in metrics:
            raise _fail(m, label, (*p, "metric"), f"metric {t['metric']!r} is not in plan {plan.title!r}"
                        f"{did_you_mean(t['metric'], metrics)}; its metrics: {', '.join(metrics)}")
        stat = t["statistic"]
        if stat not in STATISTICS:
            raise _fail(m, label, (*p, "statistic"), f"unknown statistic {stat!r}{did_you_mean(stat, STATISTICS)}; "
                        f"allowed: {', '.join(STATISTICS)}")
        role = t["role"]
        if role not in ROLES:
            raise _fail(m, label, (*p, "role"), f"role {role!r} must be fit or validation{did_you_mean(role, ROLES)}")
        where = t.get("where") or {}
        if not isinstance(where, Mapping):
            raise _fail(m, label, (*p, "where"), "where must be a mapping such as {condition: manual}")
        clean_where: dict[str, str] = {}
        for key, val in where.items():
            k = "level" if key in LEVEL_ALIASES else key
            if k not in WHERE_KEYS:
                allowed = WHERE_KEYS + LEVEL_ALIASES
                raise _fail(m, label, (*p, "where", key), f"unknown filter {key!r}{did_you_mean(key, allowed)}; "
                            f"allowed: {', '.join(allowed)}", value=False)
            known = conditions if k == "condition" else groups if k == "group" else None
            if known is not None and str(val) not in known:
                raise _fail(m, label, (*p, "where", key), f"{key} {val!r} is not in protocol {pid!r}"
                            f"{did_you_mean(val, known)}; it has {', '.join(known)}")
            clean_where[str(key)] = str(val)
        value = t["value"]
        if stat == "verdict":
            if not isinstance(value, bool):
                raise _fail(m, label, (*p, "value"), f"a verdict is true (significant) or false, got {value!r}")
        else:
            if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
                raise _fail(m, label, (*p, "value"), f"value {value!r} must be a number")
            value = float(value)
            if stat in ("sd", "cv", "iqr", "count_total") and value < 0:
                raise _fail(m, label, (*p, "value"), f"a {stat} cannot be negative ({value:g})")
            least = plan.metric_minimum(t["metric"]) if stat in ("mean", "median") else None
            if least is not None and value < least:
                unit = plan.metric_unit(t["metric"])
                raise _fail(m, label, (*p, "value"), f"a {stat} of {t['metric']!r} ({plan.metric_label(t['metric'])}"
                            f"{', ' + unit if unit else ''}) cannot be below {least:g}, got {value:g}; write the "
                            "value the paper prints (a change or difference is statistic: pct_change_vs_baseline)")
            if stat in ("proportion", "test_p") and not 0 <= value <= 1:
                raise _fail(m, label, (*p, "value"), f"a {'p-value' if stat == 'test_p' else 'proportion'} lies in "
                            f"[0, 1], got {value:g} (write 83 % as 0.83)")
        published_p = _check_published_p(m, label, p, t, stat, value, float(alpha))
        unc = t.get("uncertainty") or {}
        if not isinstance(unc, Mapping):
            raise _fail(m, label, (*p, "uncertainty"), "uncertainty is {sd: …, n: …}, {se: …} or {interval: [lo, hi]}")
        for key, val in unc.items():
            if key not in UNCERTAINTY_KEYS:
                raise _fail(m, label, (*p, "uncertainty", key), f"unknown key {key!r}"
                            f"{did_you_mean(key, UNCERTAINTY_KEYS)}; allowed: {', '.join(UNCERTAINTY_KEYS)}",
                            value=False)
            if key == "basis":
                if val not in BASES:
                    raise _fail(m, label, (*p, "uncertainty", key), f"basis {val!r} is not one of "
                                f"{', '.join(BASES)}{did_you_mean(str(val), BASES)}")
            elif key == "interval":
                if (not isinstance(val, list) or len(val) != 2
                        or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in val)
                        or not val[0] <= val[1]):
                    raise _fail(m, label, (*p, "uncertainty", key), f"interval must be [low, high] with low ≤ high, "
                                f"got {val!r}")
                if stat == "proportion" and not (0 <= val[0] and val[1] <= 1):
                    raise _fail(m, label, (*p, "uncertainty", key), f"a proportion's interval lies in [0, 1], "
                                f"got {val!r}")
            else:
                if isinstance(val, bool) or not isinstance(val, int | float) or not math.isfinite(val):
                    raise _fail(m, label, (*p, "uncertainty", key), f"{key} must be a number, got {val!r}")
                if key in ("sd", "se") and val < 0:
                    raise _fail(m, label, (*p, "uncertainty", key), f"{key} = {val:g} is negative; a spread is ≥ 0")
                if key == "n" and (val < 1 or not float(val).is_integer()):
                    raise _fail(m, label, (*p, "uncertainty", key), f"n = {val!r} must be a whole number ≥ 1")
        _check_basis(m, label, (*p, "uncertainty"), unc, stat, value)
        test = str(t.get("test") or "")
        if stat in TEST_STATISTICS:
            if not test:
                raise _fail(m, label, p, f"a {stat} target names the plan's test: test: <test id or kind> (tests: "
                            f"{', '.join(tests)})")
            if test not in tests and test not in test_kinds:
                raise _fail(m, label, (*p, "test"), f"plan {plan.title!r} has no test {test!r}"
                            f"{did_you_mean(test, list(tests) + test_kinds)}; its tests: {', '.join(tests)}")
            if test in tests and t["metric"] not in tests[test].metrics:
                raise _fail(m, label, (*p, "test"), f"test {test!r} does not test metric {t['metric']!r} (it tests "
                            f"{', '.join(tests[test].metrics)})")
        pair = _check_pair(m, label, p, t, stat, tests.get(test), conditions, groups)
        higher = _check_higher(m, label, p, t, pair)
        baseline = str(t.get("baseline") or "")
        if stat == "pct_change_vs_baseline":
            baseline = baseline or conditions[0]
            if baseline not in conditions:
                raise _fail(m, label, (*p, "baseline"), f"baseline {baseline!r} is not a condition"
                            f"{did_you_mean(baseline, conditions)}; it has {', '.join(conditions)}")
            if "condition" not in clean_where:  # noqa: SIM102
                raise _fail(m, label, (*p, "where"), "a pct_change_vs_baseline target names its condition: "
                            "where: {condition: …}")
        unit = str(t.get("unit") or "participant")
        if unit not in ("participant", "trial"):
            raise _fail(m, label, (*p, "unit"), f"unit {unit!r} must be participant (per-person means, the "
                        "default) or trial")
        mark = m.key_mark(p)
        out.append(Target(
            id=tid, metric=str(t["metric"]), statistic=stat, value=value, role=role, where=clean_where,
            uncertainty=dict(unc), note=str(t.get("note") or ""), test=test, pair=pair, higher=higher,
            baseline=baseline,
            direction_vs=str(t.get("direction_vs") or ""), unit=unit, headline=bool(t.get("headline", True)),
            location=f"{label}:{mark.line}", p=published_p,
        ))
    for i, t in enumerate(out):
        if t.direction_vs and t.direction_vs not in ids:
            raise _fail(m, label, ("targets", i, "direction_vs"), f"no target {t.direction_vs!r}"
                        f"{did_you_mean(t.direction_vs, ids)} to compare the direction with")
    return TargetSet(protocol=pid, source=str(data.get("source") or ""), targets=tuple(out), alpha=float(alpha),
                     plan=str(data.get("plan") or pid), path=label, sha256=sha256)


def _check_published_p(m: Any, label: str, p: tuple[Any, ...], t: Mapping[str, Any], stat: str, value: Any,
                       alpha: float) -> float | None:
    """A verdict's ``p``: a number in (0, 1] on the verdict's side of alpha (a p that contradicts the verdict is
    a typing slip in one of the two)."""
    if "p" not in t:
        return None
    given = t["p"]
    if stat != "verdict":
        raise _fail(m, label, (*p, "p"), f"p is the published p-value behind a verdict; a {stat} target has none "
                    "(a p-value target is statistic: test_p with the p as its value)", value=False)
    if isinstance(given, bool) or not isinstance(given, int | float) or not 0 < given <= 1:
        raise _fail(m, label, (*p, "p"), f"p {given!r} must be a p-value in (0, 1] (write 4.3e-5, not 4.3e-5 %)")
    if (given < alpha) != value:
        side = "below" if value else "at or above"
        raise _fail(m, label, (*p, "p"), f"p {given:g} contradicts value {str(value).lower()}: a "
                    f"{'significant' if value else 'non-significant'} verdict has p {side} alpha {alpha:g}; "
                    "fix the p or the value")
    return float(given)


def recomputed_interval(basis: str, value: float, n: float | None) -> tuple[float, float] | None:
    """The 95 % interval a ``wilson`` or ``exact_poisson`` basis stands for, recomputed from the published count."""
    if basis == "wilson" and n:
        from studyctl.stats import wilson_interval

        w = wilson_interval(round(value * n), int(n))
        return float(w.lower), float(w.upper)
    if basis == "exact_poisson":
        from scipy.stats import chi2

        k = round(value)
        lo = 0.0 if k == 0 else float(chi2.ppf(0.025, 2 * k) / 2)
        return lo, float(chi2.ppf(0.975, 2 * k + 2) / 2)
    return None


def _check_basis(m: Any, label: str, p: tuple[Any, ...], unc: Mapping[str, Any], stat: str, value: Any) -> None:
    """An uncertainty says what it is (``basis``); a recomputed interval must be what its published count gives."""
    given = [k for k in ("interval", "se", "sd") if k in unc]
    basis = unc.get("basis")
    if not given:
        if basis is not None:
            raise _fail(m, label, (*p, "basis"), "basis says what an interval, se or sd is; give one with it",
                        value=False)
        return
    if basis is None:
        raise _fail(m, label, (*p, given[0]), f"say what this {given[0]} is: basis: "
                    f"{' | '.join(BASES if given[0] == 'interval' else SPREAD_BASES)} (the paper's own number, "
                    "recomputed exactly from what it prints, or chosen by hand with the reason in the note)",
                    value=False)
    if "interval" not in unc and basis not in SPREAD_BASES:
        raise _fail(m, label, (*p, "basis"), f"basis {basis!r} is for an interval; an {given[0]} is "
                    f"{' | '.join(SPREAD_BASES)}")
    if basis == "wilson":
        n = unc.get("n")
        if stat != "proportion" or not n:
            raise _fail(m, label, (*p, "basis"), "basis: wilson is for a proportion and needs the published "
                        "count's n (uncertainty: {interval: …, basis: wilson, n: N})")
    if basis == "exact_poisson" and (stat != "count_total" or not float(value).is_integer()):
        raise _fail(m, label, (*p, "basis"), "basis: exact_poisson is for a count_total with a whole-number value")
    ref = recomputed_interval(str(basis), float(value), unc.get("n"))
    if ref is not None:
        lo, hi = (float(v) for v in unc["interval"])
        if abs(lo - ref[0]) > RECOMPUTE_TOLERANCE * max(1.0, abs(ref[0])) or abs(hi - ref[1]) > \
                RECOMPUTE_TOLERANCE * max(1.0, abs(ref[1])):
            of = f" of n = {float(unc['n']):g}" if basis == "wilson" else ""
            raise _fail(m, label, (*p, "interval"), f"a {basis} 95 % interval for {value:g}{of} is "
                        f"[{ref[0]:.3f}, {ref[1]:.3f}], not {unc['interval']}; fix the interval, the value or n, "
                        "or say basis: paper / chosen")


def _check_pair(m: Any, label: str, p: tuple[Any, ...], t: Mapping[str, Any], stat: str, entry: Any,
                conditions: list[str], groups: list[str]) -> tuple[str, ...]:
    """``pair: [A, B]`` of a test target: two different levels the plan's test compares (its listed pairs when
    it lists them); the simulated verdict / p is then that pair's pairwise or post-hoc row."""
    if "pair" not in t or t["pair"] is None:
        return ()
    raw = t["pair"]
    if stat not in TEST_STATISTICS:
        raise _fail(m, label, (*p, "pair"), f"pair selects a pairwise test row; it is for a verdict or test_p "
                    f"target, not a {stat}", value=False)
    if (not isinstance(raw, list) or len(raw) != 2 or not all(isinstance(v, str) for v in raw)
            or raw[0] == raw[1]):
        raise _fail(m, label, (*p, "pair"), f"pair names two different levels as a list, e.g. pair: [PHF, FF]; "
                    f"got {raw!r}")
    compare = getattr(entry, "compare", "condition") if entry is not None else "condition"
    known = conditions if compare == "condition" else groups if compare == "group" else None
    for k, v in enumerate(raw):
        if known is not None and v not in known:
            raise _fail(m, label, (*p, "pair", k), f"{compare} {v!r} is not in the protocol{did_you_mean(v, known)}; "
                        f"it has {', '.join(known)}")
    listed = getattr(entry, "pairs", None) if entry is not None else None
    if isinstance(listed, list) and listed and not any(set(raw) == set(q) for q in listed):
        names = [f"{a}-{b}" for a, b in listed]
        raise _fail(m, label, (*p, "pair"), f"test {entry.id!r} does not compare {raw[0]} with {raw[1]}"
                    f"{did_you_mean('-'.join(raw), names)}; its pairs: {', '.join(names)}")
    return (str(raw[0]), str(raw[1]))


def _check_higher(m: Any, label: str, p: tuple[Any, ...], t: Mapping[str, Any], pair: tuple[str, ...]) -> str:
    """``higher: A`` of a pair target: the paper's direction (A scored higher than the other level of ``pair``).
    A verdict then agrees only when the simulated pair is significant (or not) as the paper's AND in this
    direction; where the paper states no direction, leave it out."""
    if "higher" not in t or t["higher"] is None:
        return ""
    raw = t["higher"]
    if not pair:
        raise _fail(m, label, (*p, "higher"), "higher states the direction of a pair target; give pair: [A, B] "
                    "with it", value=False)
    if not isinstance(raw, str) or raw not in pair:
        raise _fail(m, label, (*p, "higher"), f"higher {raw!r} is not in the pair ({pair[0]}, {pair[1]})"
                    f"{did_you_mean(str(raw), list(pair))}; name the level the paper found higher")
    return raw


def shipped_targets_path(protocol_id: str) -> Path | None:
    """The targets shipped for a protocol (``studyctl/populations/<id>.targets.yaml``), or None."""
    here = Path(__file__).resolve().parent / f"{protocol_id}.targets.yaml"
    return here if here.is_file() else None
