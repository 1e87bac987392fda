"""Simulated vs published: per target agreement and the calibration distance (pure computation).

Agreement criteria (issue 17):

* **direction** — a % change vs baseline has the paper's sign; a target with ``direction_vs: OTHER`` has the
  paper's sign of (this − OTHER); other targets have no direction (blank);
* **within** — a mean, median, proportion, IQR, count or % change lies in the published band (the printed 95 %
  interval, ±1.96 SE, or ±1 SD for a mean with a printed SD; see :meth:`Target.interval`); an SD or CV is
  "within" when simulated/published lies in [1/1.5, 1.5];
* **replication** — how often a same-size replication of the paper would pass the target's check
  (:mod:`studyctl.calibration.replication`): for a verdict with a published p (a test_p target, or a verdict's
  ``p``), give its verdict; for a value whose band is the paper's sampling interval, land in it; for a spread
  with its n, lie within 1.5× (blank for a CHOSEN band): what a perfect simulation could reproduce; the summary
  adds it up (``verdict_expected``, ``within_expected``);
* **verdict** — a verdict or p-value target is significant at alpha exactly when the paper's is; for a pair
  target whose paper states a direction (``higher: A``), a significant simulated result also has to go that way
  (a significant difference the wrong way does not reproduce a significant finding), and **direction** is then
  whether the simulated people scored ``A`` higher (significant or not).

The calibration distance is the simulated method of moments objective: Σ over fit targets of
((simulated − published) / σ)², σ² = published SE² + simulation SE² (a p-value as its normal deviate, see
:func:`p_value_z`; a verdict that differs adds 4, i.e. a 2σ miss, and a significant result against the paper's
stated direction 16; a target the simulation cannot compute adds 25).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass

import pandas as pd

from studyctl.calibration.replication import band_replication, spread_replication, verdict_replication
from studyctl.calibration.simulated import SimulatedStats
from studyctl.populations.targets import SPREADS, Target, statistic_limits

SD_FACTOR = 1.5
MISSING_PENALTY = 25.0
VERDICT_PENALTY = 4.0
WRONG_WAY_PENALTY = 16.0  # significant, but the other level is higher than the paper found
# A p-value is compared as the normal deviate it stands for, z = Φ⁻¹(1 − p/2). A replication of a study with
# the same n draws its own deviate around the same true effect with SD 1, as the published one did, so two
# studies' deviates differ by SD √2 (Cumming 2008, "Replication and p intervals", Perspect. Psychol. Sci. 3:286;
# Boos & Stefanski 2011, Am. Stat. 65:213, on how little of a p-value reproduces). The earlier σ = 0.5 in log10 p
# made a p-value target's distance grow without bound as a simulated effect grew (p 3e-6 against a published
# 0.034: 65 in z², more than every other validation target of seed 001 together; stop 30's note).
P_DEVIATE_SD = math.sqrt(2.0)

COLUMNS = (
    "target", "role", "metric", "where", "statistic", "published", "published_low", "published_high", "band",
    "simulated", "simulated_low", "simulated_high", "same_direction", "within", "sd_ratio", "same_verdict",
    "replication", "agrees", "z", "note",
)


@dataclass(frozen=True)
class AgreementRow:
    target: str
    role: str
    metric: str
    where: str
    statistic: str
    published: float | bool
    published_low: float
    published_high: float
    band: str
    simulated: float | bool
    simulated_low: float
    simulated_high: float
    same_direction: bool | None
    within: bool | None
    sd_ratio: float
    same_verdict: bool | None
    replication: float  # how often a same-size replication of the paper passes this check (NaN: not known)
    agrees: bool | None
    z: float
    note: str


@dataclass(frozen=True)
class Agreement:
    rows: tuple[AgreementRow, ...]
    alpha: float

    def to_frame(self) -> pd.DataFrame:
        return pd.DataFrame([asdict(r) for r in self.rows], columns=list(COLUMNS))

    def summary(self) -> dict[str, dict[str, float | int | None]]:
        """See :func:`summary_from_frame`."""
        return summary_from_frame(self.to_frame())


CHECKS = ("same_direction", "within", "same_verdict", "agrees")  # the yes/no columns


def checks_as_booleans(frame: pd.DataFrame) -> pd.DataFrame:
    """An ``agreement.csv`` as read back (``pd.read_csv``): its yes/no columns as booleans again, None where a check
    does not apply (blank), so :func:`summary_from_frame` counts them as the report did."""
    out = frame.copy()
    for col in CHECKS:
        out[col] = out[col].map(lambda v: None if pd.isna(v) else str(v) == "True")
    return out


def _present(v: object) -> bool:
    return v is not None and not (isinstance(v, float) and math.isnan(v))


def summary_from_frame(frame: pd.DataFrame) -> dict[str, dict[str, float | int | None]]:
    """Per role (fit, validation, all): fractions of directions right, verdicts reproduced, values within their
    band (SDs apart), SD ratios within 1.5×, targets that agree on every check, and the counts behind them; of the
    verdicts with a published p, how many were reproduced (``verdict_p_reproduced`` of ``verdict_p_n``) and how
    many a same-size replication of the paper would reproduce on average (``verdict_expected``), and the same for
    the values whose band is the paper's sampling interval (``within_p_reproduced`` of ``within_p_n``,
    ``within_expected``). An ``agreement.csv`` written before the replication column has none of either."""
    out: dict[str, dict[str, float | int | None]] = {}
    records = frame.to_dict("records")
    for role in ("fit", "validation", "all"):
        rows = [r for r in records if role == "all" or r["role"] == role]
        figures: dict[str, float | int | None] = {"targets": len(rows)}
        for name, col in (("direction", "same_direction"), ("verdict", "same_verdict"), ("within", "within"),
                          ("agree", "agrees")):
            vals = [bool(r[col]) for r in rows
                    if _present(r[col]) and (col != "within" or r["statistic"] not in SPREADS)]
            figures[f"{name}_n"] = len(vals)
            figures[f"{name}_fraction"] = (sum(vals) / len(vals)) if vals else None
        # what chance alone allows: the verdicts with a published p, and the values whose band is the paper's own
        # sampling interval (spreads apart, as within_n), reproduced and expected of a replication
        _against_chance(figures, "verdict", [r for r in rows if _present(r["same_verdict"])])
        _against_chance(figures, "within", [r for r in rows if r["statistic"] not in SPREADS and _present(r["within"])])
        sds = [r for r in rows if r["statistic"] in SPREADS and _present(r["within"])]
        figures["sd_ratio_n"] = len(sds)
        figures["sd_ratio_within_fraction"] = (sum(bool(r["within"]) for r in sds) / len(sds)) if sds else None
        ratios = [float(r["sd_ratio"]) for r in sds if _present(r["sd_ratio"])]
        figures["sd_ratio_median"] = float(pd.Series(ratios).median()) if ratios else None
        out[role] = figures
    return out


def _against_chance(figures: dict[str, float | int | None], name: str, rows: list[dict]) -> None:
    """``{name}_p_n``, ``{name}_p_reproduced``, ``{name}_expected`` and ``{name}_expected_fraction`` over the
    ``rows`` (checked by ``name``'s column) that have a replication figure."""
    col = "same_verdict" if name == "verdict" else name
    kept = [r for r in rows if _present(r.get("replication"))]
    expected = float(sum(float(r["replication"]) for r in kept)) if kept else None
    figures[f"{name}_p_n"] = len(kept)
    figures[f"{name}_p_reproduced"] = sum(bool(r[col]) for r in kept)
    figures[f"{name}_expected"] = expected
    figures[f"{name}_expected_fraction"] = (expected / len(kept)) if expected is not None else None


def _num(v: object) -> float:
    if isinstance(v, bool):
        return float(v)
    try:
        return float(v)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return math.nan


def _sign(x: float) -> int:
    return 0 if x == 0 else (1 if x > 0 else -1)


def wrong_way(t: Target, higher: str) -> bool:
    """A pair target with the paper's direction whose simulated people scored the other level higher."""
    return bool(t.higher) and higher != t.higher


def _significant(t: Target, sim: object, alpha: float) -> bool | None:
    if t.statistic == "verdict":
        return sim if isinstance(sim, bool) else None
    s = _num(sim)
    return bool(s < alpha) if math.isfinite(s) else None


def p_value_z(simulated_p: float, published_p: float) -> float:
    """Distance of a simulated p from the published one in σ units of a replication (module docs): negative when
    the simulated people give the smaller p, i.e. the stronger evidence."""
    from scipy.stats import norm  # lazy: importing scipy.stats costs about a second (test collection imports this)

    deviate = [float(norm.isf(min(max(p, 1e-300), 1.0) / 2.0)) for p in (simulated_p, published_p)]
    return (deviate[1] - deviate[0]) / P_DEVIATE_SD


def z_score(t: Target, sim: object, sim_se: float, alpha: float, higher: str = "") -> float:
    """Signed distance of the simulated value from the published one in σ units (see the module docs);
    ``higher``: the level of a pair target the simulated people scored higher on."""
    if t.is_test and t.higher and t.value and _significant(t, sim, alpha) and wrong_way(t, higher):
        return -math.sqrt(WRONG_WAY_PENALTY)
    if t.statistic == "verdict":
        if not isinstance(sim, bool):
            return math.nan
        return 0.0 if sim == t.value else math.copysign(math.sqrt(VERDICT_PENALTY), 1.0 if sim else -1.0)
    s = _num(sim)
    if not math.isfinite(s):
        return math.nan
    if t.statistic == "test_p":
        return p_value_z(s, float(t.value))
    se_pub = t.published_se()
    if se_pub is None:
        se_pub = max(abs(float(t.value)) * 0.1, 1e-6)  # an unstated uncertainty: 10 % of the value
    var = se_pub**2 + (sim_se**2 if math.isfinite(sim_se) else 0.0)
    return (s - float(t.value)) / math.sqrt(max(var, 1e-12))


def distance(targets: Sequence[Target], sim: SimulatedStats, alpha: float,
             sim_se: Mapping[str, float] | None = None) -> tuple[float, dict[str, float]]:
    """The calibration distance over ``targets`` and each target's z (see the module docs).

    ``sim_se`` fixes the simulation SE per target (so the weights stay the same for every candidate);
    default: each value's own bootstrap SE.
    """
    total, zs = 0.0, {}
    for t in targets:
        v = sim.get(t.id)
        z = z_score(t, v.value, (sim_se or {}).get(t.id, v.se), alpha, v.higher)
        zs[t.id] = z
        total += MISSING_PENALTY if not math.isfinite(z) else z * z
    return total, zs


def _where(t: Target) -> str:
    parts = [f"{k}={w}" for k, w in t.where.items()]
    if t.pair:
        parts.append(f"pair={t.pair[0]} vs {t.pair[1]}")
    return ", ".join(parts)


def _replication(t: Target, alpha: float, published_sig: bool, band: tuple[float, float] | None) -> float:
    """How often a same-size replication of the paper passes this target's check (NaN where that is unknown: a
    verdict without a published p, a CHOSEN band, a spread without n; :mod:`studyctl.calibration.replication`)."""
    if t.is_test:
        pp = t.published_p()
        return math.nan if pp is None else verdict_replication(
            pp, alpha, significant=published_sig, directed=published_sig and bool(t.higher))
    if t.uncertainty.get("basis") == "chosen":
        return math.nan
    if t.statistic in SPREADS:
        n = t.uncertainty.get("n")
        return spread_replication(float(n), SD_FACTOR) if n and float(n) > 1 else math.nan
    se = t.published_se()
    if band is None or se is None or not se > 0:
        return math.nan
    lo, hi = band
    # a band edge at the statistic's own limit cannot be crossed (a proportion above 1, a count below 0)
    low, high = statistic_limits(t.statistic)
    if lo <= low:
        lo = -math.inf
    if hi >= high:
        hi = math.inf
    return band_replication(float(t.value), se, lo, hi)


def agreement(targets: Sequence[Target], sim: SimulatedStats, alpha: float) -> Agreement:
    """Each target against its simulated value (see the module docs for the criteria)."""
    pub = {t.id: t for t in targets}
    rows = []
    for t in targets:
        v = sim.get(t.id)
        s = v.value
        band = t.interval()
        lo, hi = band if band else (math.nan, math.nan)
        if t.statistic in SPREADS and float(t.value) > 0:  # a spread is judged by its ratio: show that band
            lo, hi = float(t.value) / SD_FACTOR, float(t.value) * SD_FACTOR
        direction = within = verdict = None
        ratio = math.nan
        sn = _num(s)
        if t.statistic == "pct_change_vs_baseline" and math.isfinite(sn):
            direction = _sign(sn) == _sign(float(t.value))
        if t.direction_vs and t.direction_vs in pub and not t.is_test:
            other = sim.get(t.direction_vs)
            on = _num(other.value)
            if math.isfinite(sn) and math.isfinite(on):
                direction = _sign(sn - on) == _sign(float(t.value) - float(pub[t.direction_vs].value))
        if t.is_test and t.higher:
            direction = not wrong_way(t, v.higher)
        if t.statistic in SPREADS and math.isfinite(sn) and float(t.value) > 0:
            ratio = sn / float(t.value)
            within = 1 / SD_FACTOR <= ratio <= SD_FACTOR
        elif not t.is_test and band is not None and math.isfinite(sn):
            within = lo <= sn <= hi
        elif not t.is_test and band is not None:
            within = False
        if t.statistic == "verdict":
            verdict = (s == t.value) if isinstance(s, bool) else False
        elif t.statistic == "test_p":
            verdict = (sn < alpha) == (float(t.value) < alpha) if math.isfinite(sn) else False
        published_sig = bool(t.value) if t.statistic == "verdict" else t.is_test and float(t.value) < alpha
        if verdict and published_sig and t.higher and wrong_way(t, v.higher):
            verdict = False  # significant, but the other way round: not the paper's finding
        replication = _replication(t, alpha, published_sig, band)
        checks = [c for c in (direction, within, verdict) if c is not None]
        agrees = all(checks) if checks else None
        z = z_score(t, s, v.se, alpha, v.higher)
        rows.append(AgreementRow(
            target=t.id, role=t.role, metric=t.metric, where=_where(t),
            statistic=t.statistic, published=t.value, published_low=lo, published_high=hi, band=t.band(),
            simulated=s, simulated_low=v.low, simulated_high=v.high, same_direction=direction, within=within,
            sd_ratio=ratio, same_verdict=verdict, replication=replication, agrees=agrees, z=z, note=v.note,
        ))
    return Agreement(tuple(rows), alpha)
