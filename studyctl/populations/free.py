"""Free parameters of a population: what ``studyctl calibrate --free`` may change, and their search bounds.

Names:

* ``TRAIT`` or ``TRAIT.mean`` — the trait's location (mean / median);
* ``TRAIT.sd`` — its between-person spread;
* ``TRAIT@GROUP`` or ``TRAIT@GROUP.mean`` / ``TRAIT@GROUP.sd`` — the location / spread of one stratum;
* ``NAME`` for a ``fixed:`` parameter (the same value for everyone).

Bounds come from the population file's ``calibration.bounds`` when given, else: a location within the
trait's range (searched on the log scale for lognormal traits, the logit scale for logitnormal ones); an
SD within [0, half the range] for normal traits and [0, 1.5] on the log/logit scale otherwise; a fixed
parameter within the participant's declared range (which must then be finite).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

from studyctl.errors import PopulationError
from studyctl.populations.model import TraitPopulation
from studyctl.suggest import did_you_mean


@dataclass(frozen=True)
class FreeParam:
    """One free parameter: where it lives, its bounds, its current value and the search scale."""

    name: str
    trait: str | None  # None: a fixed parameter
    group: str | None
    key: str  # "mean" | "sd" | "value"
    low: float
    high: float
    value: float
    scale: str = "linear"  # linear | log | logit

    def to_search(self, v: float) -> float:
        if self.scale == "log":
            return math.log(v)
        if self.scale == "logit":
            return math.log(v / (1 - v))
        return v

    def from_search(self, u: float) -> float:
        if self.scale == "log":
            return math.exp(u)
        if self.scale == "logit":
            return 1 / (1 + math.exp(-u))
        return u

    @property
    def search_bounds(self) -> tuple[float, float]:
        return self.to_search(self.low), self.to_search(self.high)


def _parse(name: str) -> tuple[str, str | None, str]:
    base, group, key = name, None, "mean"
    for k in ("mean", "sd"):
        if base.endswith("." + k):
            base, key = base[: -len(k) - 1], k
    if "@" in base:
        base, group = base.split("@", 1)
    return base, group, key


def free_params(pop: TraitPopulation, names: Sequence[str], *, declared: Mapping[str, Any] | None = None,
                strata: Sequence[str] | None = None) -> tuple[FreeParam, ...]:
    """Check ``names`` against ``pop`` (and a ``TRAIT@GROUP``'s group against ``strata`` when given) and give
    each one's bounds (see the module docs)."""
    if not names:
        raise PopulationError("no free parameters: give --free TRAIT,TRAIT.sd,… (or calibration.free in the "
                              f"population file); traits of {pop.name}: {', '.join(t.name for t in pop.traits)}")
    if declared is None:
        from studyctl.plugins.registry import load_plugin
        from studyctl.populations.loader import participant_params

        declared = participant_params(load_plugin("participant", pop.participant))
    bounds = dict(pop.calibration.get("bounds") or {})
    trait_names = [t.name for t in pop.traits]
    valid = trait_names + [f"{t}.sd" for t in trait_names] + list(pop.fixed)
    out: list[FreeParam] = []
    seen: set[str] = set()
    for name in names:
        name = name.strip()
        if not name:
            continue
        if name in seen:
            raise PopulationError(f"free parameter {name!r} given twice")
        seen.add(name)
        base, group, key = _parse(name)
        if base in pop.fixed and group is None and key == "mean" and base not in trait_names:
            value = pop.fixed[base]
            p = declared.get(base)
            low = None if p is None or p.low is None else float(p.low)
            high = None if p is None or p.high is None else float(p.high)
            if name in bounds:
                low, high = (float(b) for b in bounds[name])
            if low is None or high is None or not (math.isfinite(low) and math.isfinite(high)):
                raise PopulationError(f"free parameter {name!r} (fixed) has no finite range; give "
                                      f"calibration.bounds: {{{name}: [low, high]}} in the population file")
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise PopulationError(f"free parameter {name!r} is not a number ({value!r}); only numbers are fitted")
            out.append(FreeParam(name, None, None, "value", low, high, float(value)))
            continue
        if base not in trait_names:
            raise PopulationError(f"free parameter {name!r}: {pop.name} has no trait or fixed parameter {base!r}"
                                  f"{did_you_mean(base, trait_names + list(pop.fixed))}; free names: "
                                  f"{', '.join(valid)} (TRAIT@GROUP for a stratum)")
        t = pop.trait(base)
        if group is not None and strata is not None and group not in strata:
            raise PopulationError(f"free parameter {name!r}: the protocol has no stratum {group!r}"
                                  f"{did_you_mean(group, strata)}; its strata: {', '.join(strata)}")
        if t.dist == "fixed" and key == "sd":
            raise PopulationError(f"free parameter {name!r}: trait {base} is fixed (no spread); make it normal, "
                                  "lognormal or logitnormal first")
        current = t.location(group) if key == "mean" else t.spread(group)
        scale = "linear"
        if key == "mean":
            low, high = t.low, t.high
            if t.dist == "lognormal":
                low, scale = max(low, 1e-9 * max(high, 1.0)), "log"
            elif t.dist == "logitnormal":
                low, high, scale = max(low, 1e-4), min(high, 1 - 1e-4), "logit"
        else:
            low, high = 0.0, (t.high - t.low) / 2 if t.dist == "normal" else 1.5
        if name in bounds:
            try:
                low, high = (float(b) for b in bounds[name])
            except (TypeError, ValueError):
                raise PopulationError(f"calibration.bounds.{name} must be [low, high]") from None
        if not (math.isfinite(low) and math.isfinite(high) and low < high):
            raise PopulationError(f"free parameter {name!r}: no finite search range [{low:g}, {high:g}]; give "
                                  f"calibration.bounds: {{{name}: [low, high]}}")
        out.append(FreeParam(name, base, group, key, low, high, min(max(float(current), low), high), scale))
    return tuple(out)


def apply_values(pop: TraitPopulation, values: Mapping[str, float], free: Sequence[FreeParam] | None = None
                 ) -> TraitPopulation:
    """``pop`` with the named free parameters set (sources of the changed traits become FITTED)."""
    specs = {f.name: f for f in (free or free_params(pop, list(values)))}
    traits = {t.name: t for t in pop.traits}
    fixed = dict(pop.fixed)
    for name, v in values.items():
        f = specs[name]
        if f.trait is None:
            fixed[name] = int(round(v)) if isinstance(pop.fixed[name], int) else float(v)
            continue
        t = traits[f.trait]
        if f.group is None:
            t = replace(t, **{f.key: float(v)})
        else:
            groups = {g: dict(x) for g, x in t.groups.items()}
            groups.setdefault(f.group, {})[f.key] = float(v)
            t = replace(t, groups=groups)
        traits[f.trait] = t
    return replace(pop, traits=tuple(traits.values()), fixed=fixed, sha256="", path="")


def mark_fitted(pop: TraitPopulation, free: Sequence[FreeParam], note: str) -> TraitPopulation:
    """Sources of traits with a fitted parameter become ``FITTED: <note> (was: <old source>)``."""
    touched = {f.trait for f in free if f.trait}
    traits = []
    for t in pop.traits:
        if t.name in touched and not t.source.startswith("FITTED"):
            t = replace(t, source=f"FITTED: {note} (prior: {t.source})")
        traits.append(t)
    return replace(pop, traits=tuple(traits), sha256="", path="")
