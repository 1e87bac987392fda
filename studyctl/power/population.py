"""What a simulated participant population looks like: the knobs that set the simulated effect sizes.

A power analysis is only as honest as the effect it simulates, so the effect is stated here rather than
left to whatever the virtual participants happen to do. The knobs act on the **perception (and motor)
parameters of the protocol's virtual participant** — the names its constructor declares
(``VirtualPalpator.PARAMS``, ``VirtualTissuePalpator.PARAMS``, the needle operator's ``DEFAULTS``) —
as *additive* shifts::

    value(participant i, condition c) = base + group_shift[stratum of i] + condition_shift[c] + u_i
    u_i ~ Normal(0, between_sd)   drawn once per participant and parameter (the replicate's seed)

``base`` is the parameter's default, overridden by the protocol's ``participants.virtual.params`` and then
by ``baseline``. Values are clipped to the parameter's declared range (parameters without a declared
range, e.g. the needle operator's, are kept ≥ 0 when their default is positive); clipping is counted in
each replicate's result so that a spread wide enough to hit a bound is visible.

On top of these knobs every condition still differs through what the engine simulates — the controller
turns tumour stiffness into feedback or not — so with an empty population the power reflects the
simulated physics and perception alone. The knobs state extra effects in the parameters' own units.

YAML form (a file given to ``studyctl power --population``)::

    population:
      baseline:        {balloon_weber: 0.12}          # absolute values (replace the base)
      condition_effects:                              # additive, per condition id
        bio_inspired:  {balloon_weber: -0.04}
      group_effects:                                  # additive, per stratum id
        expert:        {aim_sd_mm: -0.8, depth_cv: -0.02}
      between_sd:      {balloon_weber: 0.02, aim_sd_mm: 0.4}   # SD of each participant's own offset
"""

from __future__ import annotations

import hashlib
import json
import math
import sys
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np
import pandas as pd

from studyctl.engine.factory import EntryPointFactory
from studyctl.errors import ModelParameterError, NotFoundError, ProtocolError, UsageError
from studyctl.inputs import read_text
from studyctl.plugins.interfaces import Action, Participant, TrialInfo
from studyctl.suggest import nearest
from studyctl.yamlmarks import load_plain

_SECTIONS = ("baseline", "condition_effects", "group_effects", "between_sd")


def _frozen(mapping: Mapping[str, Any]) -> Mapping[str, Any]:
    return MappingProxyType(dict(mapping))


@dataclass(frozen=True)
class Population:
    """The simulated population: additive shifts of the virtual participant's parameters.

    Attributes
    ----------
    baseline
        ``{param: value}`` absolute values replacing the base value (default and protocol's params).
    condition_effects
        ``{condition id: {param: shift}}`` added in trials of that condition (the within-subject effect).
    group_effects
        ``{stratum id: {param: shift}}`` added for every participant of that stratum (group difference).
    between_sd
        ``{param: sd}`` standard deviation of each participant's own offset ``u_i ~ N(0, sd)``
        (between-participant variability), drawn once per participant and replicate.
    """

    baseline: Mapping[str, float] = field(default_factory=dict)
    condition_effects: Mapping[str, Mapping[str, float]] = field(default_factory=dict)
    group_effects: Mapping[str, Mapping[str, float]] = field(default_factory=dict)
    between_sd: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "baseline", _frozen(_numbers(self.baseline, "baseline")))
        object.__setattr__(self, "between_sd", _frozen(_numbers(self.between_sd, "between_sd")))
        for name in ("condition_effects", "group_effects"):
            raw = getattr(self, name)
            if not isinstance(raw, Mapping):
                raise UsageError(f"population {name} must map ids to {{parameter: shift}}, got {raw!r}")
            object.__setattr__(
                self, name, _frozen({str(k): _frozen(_numbers(v, f"{name}.{k}")) for k, v in raw.items()})
            )
        for param, sd in self.between_sd.items():
            if sd < 0:
                raise UsageError(f"population between_sd.{param} = {sd:g} must be ≥ 0 (a standard deviation)")

    def __reduce__(self) -> tuple:
        # mapping proxies do not pickle: rebuild from plain dicts (process pools, Dask workers)
        d = self.to_dict()
        return (Population, (d["baseline"], d["condition_effects"], d["group_effects"], d["between_sd"]))

    @property
    def is_empty(self) -> bool:
        return not (
            self.baseline or self.between_sd or any(self.condition_effects.values()) or any(self.group_effects.values())
        )

    def parameters(self) -> list[str]:
        """Every parameter a knob mentions, sorted."""
        names = set(self.baseline) | set(self.between_sd)
        for shifts in (*self.condition_effects.values(), *self.group_effects.values()):
            names |= set(shifts)
        return sorted(names)

    def to_dict(self) -> dict[str, Any]:
        """Plain (YAML/JSON-able) form, keys sorted."""
        return {
            "baseline": dict(sorted(self.baseline.items())),
            "condition_effects": {k: dict(sorted(v.items())) for k, v in sorted(self.condition_effects.items())},
            "group_effects": {k: dict(sorted(v.items())) for k, v in sorted(self.group_effects.items())},
            "between_sd": dict(sorted(self.between_sd.items())),
        }

    def sha256(self) -> str:
        return hashlib.sha256(json.dumps(self.to_dict(), sort_keys=True).encode()).hexdigest()

    def merged(self, other: Population) -> Population:
        """This population with ``other``'s entries added or replacing (command-line knobs over a file)."""
        cond = {k: dict(v) for k, v in self.condition_effects.items()}
        for k, v in other.condition_effects.items():
            cond.setdefault(k, {}).update(v)
        grp = {k: dict(v) for k, v in self.group_effects.items()}
        for k, v in other.group_effects.items():
            grp.setdefault(k, {}).update(v)
        return Population({**self.baseline, **other.baseline}, cond, grp, {**self.between_sd, **other.between_sd})


def _numbers(raw: Any, where: str) -> dict[str, float]:
    if raw is None:
        return {}
    if not isinstance(raw, Mapping):
        raise UsageError(f"population {where} must map parameter names to numbers, got {raw!r}")
    out = {}
    for key, value in raw.items():
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise UsageError(f"population {where}.{key} = {value!r} must be a finite number")
        out[str(key)] = float(value)
    return out


def load_population(path: str | Path) -> Population:
    """Read the ``population:`` section of a YAML file (the whole file may also be just that section)."""

    file = Path(path)
    if not file.is_file():
        raise NotFoundError(
            f"population file {str(path)!r} does not exist; pass a YAML file with a population: section"
        )

    try:
        data = load_plain(read_text(file, "population file", error=ProtocolError), str(file))
    except UsageError as exc:
        raise ProtocolError(f"not valid YAML: {exc}") from None
    if isinstance(data, Mapping) and "population" in data:
        data = data["population"]
    if data is None:
        return Population()
    if not isinstance(data, Mapping):
        raise ProtocolError(f"{file}: the population section must be a mapping with {', '.join(_SECTIONS)}")
    unknown = sorted(set(data) - set(_SECTIONS))
    if unknown:
        raise ProtocolError(f"{file}: population: unknown key(s) {', '.join(unknown)}; allowed: {', '.join(_SECTIONS)}")
    try:
        return Population(**{k: data.get(k) or {} for k in _SECTIONS})
    except UsageError as exc:
        raise ProtocolError(f"{file}: {exc}") from None


def parse_knob(text: str, option: str, *, keyed: bool) -> tuple[str | None, str, float]:
    """Parse a command-line knob ``KEY:PARAM=VALUE`` (``keyed``) or ``PARAM=VALUE``."""
    form = "CONDITION_OR_GROUP:PARAM=NUMBER" if keyed else "PARAM=NUMBER"
    head, sep, value = text.partition("=")
    key = None
    if keyed:
        key, colon, head = head.partition(":")
        if not colon or not key:
            raise UsageError(f"{option} {text!r}: expected {form}, e.g. bio_inspired:balloon_weber=-0.03")
    if not sep or not head:
        raise UsageError(f"{option} {text!r}: expected {form}")
    try:
        number = float(value)
    except ValueError:
        raise UsageError(f"{option} {text!r}: {value!r} is not a number") from None
    if not math.isfinite(number):
        raise UsageError(f"{option} {text!r}: the value must be finite")
    return key, head.strip(), number


# ------------------------------------------------------------------------------ parameter spaces


@dataclass(frozen=True)
class ParamRange:
    """A shiftable real-valued parameter of a participant plugin and its allowed range."""

    name: str
    default: float
    low: float
    high: float


def param_space(cls: type) -> dict[str, ParamRange]:
    """The real-valued parameters a participant class declares (``PARAMS`` or its module's ``DEFAULTS``)."""
    spec = getattr(cls, "PARAMS", None)
    out: dict[str, ParamRange] = {}
    if spec:
        for p in spec:
            if getattr(p, "kind", float) is float and isinstance(p.default, int | float):
                low = -math.inf if p.low is None else float(p.low)
                high = math.inf if p.high is None else float(p.high)
                out[p.name] = ParamRange(p.name, float(p.default), low, high)
        return out
    defaults = getattr(sys.modules.get(cls.__module__), "DEFAULTS", None)
    if isinstance(defaults, Mapping):
        for name, value in defaults.items():
            if isinstance(value, int | float) and not isinstance(value, bool):
                out[name] = ParamRange(name, float(value), 0.0 if value > 0 else -math.inf, math.inf)
        return out
    raise UsageError(
        f"participant plugin {getattr(cls, 'name', cls.__name__)!r} declares no parameters "
        "(PARAMS or DEFAULTS); population knobs need its parameter names"
    )


@dataclass(frozen=True)
class PopulationModel:
    """A population checked against one protocol's virtual participant: builds each participant's actor."""

    population: Population
    plugin: str
    plugin_cls: type
    space: Mapping[str, ParamRange]
    protocol_params: Mapping[str, Any]
    conditions: tuple[str, ...]
    strata: tuple[str, ...]

    def base(self, person: Mapping[str, Any] | None = None) -> dict[str, float]:
        """Every shiftable parameter's base value (default < protocol params < the person's drawn traits and
        fixed params from a population file < baseline)."""
        out = {name: r.default for name, r in self.space.items()}
        out.update({k: float(v) for k, v in self.protocol_params.items() if k in self.space})
        out.update({k: float(v) for k, v in (person or {}).items() if k in self.space})
        out.update(self.population.baseline)
        return out

    def draw_offsets(self, rng: np.random.Generator) -> dict[str, float]:
        """One participant's own offsets ``u_i`` (parameters in sorted order: the draw order is fixed)."""
        return {p: float(rng.normal(0.0, sd)) for p, sd in sorted(self.population.between_sd.items()) if sd > 0}

    def values(self, stratum: str, condition: str, offsets: Mapping[str, float],
               person: Mapping[str, Any] | None = None) -> tuple[dict[str, float], int]:
        """The knob-set parameters of one participant in one condition, and how many were clipped."""
        base = self.base(person)
        shifted = {p: base[p] for p in self.population.parameters()}
        for shifts in (
            self.population.group_effects.get(stratum, {}),
            self.population.condition_effects.get(condition, {}),
            offsets,
        ):
            for p, d in shifts.items():
                shifted[p] = shifted[p] + d
        clipped = 0
        for p, v in shifted.items():
            r = self.space[p]
            c = min(max(v, r.low), r.high)
            clipped += c != v
            shifted[p] = c
        return shifted, clipped

    def actor(self, stratum: str, offsets: Mapping[str, float], person: Mapping[str, Any] | None = None
              ) -> tuple[Participant, int]:
        """The virtual participant for a participant of ``stratum`` with its offsets, and the clip count.

        ``person``: the constructor params a population file drew for this person (its traits and fixed
        params); the knobs shift on top of them."""
        by_condition: dict[str, dict[str, Any]] = {}
        clipped = 0
        for c in self.conditions:
            vals, n = self.values(stratum, c, offsets, person)
            clipped += n
            by_condition[c] = {**self.protocol_params, **(person or {}), **vals}
        return PopulationParticipant(self.plugin_cls, by_condition), clipped

    def to_frame(self) -> pd.DataFrame:
        """The stated population, one row per parameter a knob touches (what the report folder shows).

        Columns: ``parameter, base, between_sd, low, high`` then ``condition:<id>`` and ``group:<id>``
        shifts (0 where a knob leaves the parameter alone).
        """
        base = self.base()
        rows = []
        for p in self.population.parameters():
            r = self.space[p]
            row = {
                "parameter": p,
                "base": base[p],
                "between_sd": self.population.between_sd.get(p, 0.0),
                "low": r.low,
                "high": r.high,
            }
            for c in self.conditions:
                row[f"condition:{c}"] = self.population.condition_effects.get(c, {}).get(p, 0.0)
            for g in self.strata:
                row[f"group:{g}"] = self.population.group_effects.get(g, {}).get(p, 0.0)
            rows.append(row)
        cols = [
            "parameter",
            "base",
            "between_sd",
            "low",
            "high",
            *(f"condition:{c}" for c in self.conditions),
            *(f"group:{g}" for g in self.strata),
        ]
        return pd.DataFrame(rows, columns=cols)


def population_model(population: Population, protocol: Any, factory: Any | None = None) -> PopulationModel:
    """Check a population against a protocol's virtual participant (names, ids, ranges) before any work.

    Raises
    ------
    UsageError
        The protocol names no virtual participant; a knob names an unknown parameter, condition or
        group, or a whole-number parameter; the shifted values (without the random offsets) are out of
        range or rejected by the participant's constructor.
    """
    ref = protocol.participants.virtual
    if ref is None:
        raise UsageError(
            f"protocol {protocol.study.id!r} names no virtual participant (participants.virtual); "
            "a power analysis simulates participants: add one, e.g. virtual: {plugin: virtual_palpator}"
        )
    factory = factory or EntryPointFactory()
    cls = factory.load("participant", ref.plugin)
    space = param_space(cls)
    conditions, strata = tuple(protocol.condition_ids), tuple(protocol.stratum_ids)
    for section, keys, known in (
        ("condition_effects", population.condition_effects, conditions),
        ("group_effects", population.group_effects, strata),
    ):
        for key in keys:
            if key not in known:
                what = "condition" if section == "condition_effects" else "group (stratum)"
                raise UsageError(
                    f"population {section}: protocol {protocol.study.id!r} has no {what} {key!r}; "
                    f"it has {', '.join(known)}"
                )
    all_names = {p.name for p in getattr(cls, "PARAMS", ())} or set(space)
    for p in population.parameters():
        if p not in space:
            if p in all_names:
                raise UsageError(
                    f"population: parameter {p!r} of {ref.plugin} is not a real number; knobs shift "
                    f"real-valued parameters only ({', '.join(sorted(space))})"
                )
            near = nearest(p, space)
            raise UsageError(
                f"population: {ref.plugin} has no parameter {p!r}"
                + (f" (did you mean {near!r}?)" if near else "")
                + f"; its real-valued parameters: {', '.join(sorted(space))}"
            )
    model = PopulationModel(
        population, ref.plugin, cls, MappingProxyType(space), MappingProxyType(dict(ref.params)), conditions, strata
    )
    for g in strata:
        for c in conditions:
            vals, _ = model.values(g, c, {})
            for p, v in vals.items():
                raw = (
                    model.base()[p]
                    + population.group_effects.get(g, {}).get(p, 0.0)
                    + population.condition_effects.get(c, {}).get(p, 0.0)
                )
                if raw != v:
                    r = space[p]
                    raise UsageError(
                        f"population: {p} = {raw:g} for group {g!r} in condition {c!r} is outside "
                        f"{ref.plugin}'s range [{r.low:g}, {r.high:g}]; make the shifts smaller"
                    )
            try:
                cls(params={**dict(ref.params), **vals})
            except ModelParameterError as exc:
                raise UsageError(f"population for group {g!r}, condition {c!r}: {exc}") from None
    return model


# ------------------------------------------------------------------------------ the participant


class PopulationParticipant(Participant):
    """One virtual participant whose parameters depend on the trial's condition.

    It delegates to an instance of the protocol's participant plugin built with the condition's
    parameters (one instance when the parameters are the same in every condition). What a participant
    carries from trial to trial stays with the participant, not with the condition: attributes a freshly
    built instance starts empty (``None``, empty list/dict/set — e.g. the needle operator's ``traits``,
    ``history`` and learnt cues) move to the next condition's instance when the condition changes.
    """

    name = "population"
    virtual = True

    def __init__(self, plugin_cls: type, params_by_condition: Mapping[str, Mapping[str, Any]]) -> None:
        super().__init__({})
        self.plugin_cls = plugin_cls
        self.params_by_condition = {c: dict(p) for c, p in params_by_condition.items()}
        distinct = {json.dumps(p, sort_keys=True, default=str) for p in self.params_by_condition.values()}
        self._shared = len(distinct) <= 1
        self._instances: dict[str, Participant] = {}
        self._memory_keys: dict[str, tuple[str, ...]] = {}
        self._active: Participant | None = None
        self._session_state: dict[str, Any] | None = None

    def begin_session(self, rng: np.random.Generator) -> None:
        """Pass the engine's once-per-session stream on, so per-person traits survive a resume."""
        self._session_state = rng.bit_generator.state
        for inst in self._instances.values():
            self._begin_session(inst)

    def _begin_session(self, inst: Participant) -> None:
        begin = getattr(inst, "begin_session", None)
        if callable(begin) and self._session_state is not None:
            bit_generator = type(np.random.default_rng().bit_generator)()
            bit_generator.state = self._session_state
            begin(np.random.Generator(bit_generator))

    def instance_for(self, condition: str) -> Participant:
        """The plugin instance that acts in ``condition`` (built on first use)."""
        key = "*" if self._shared else condition
        if key not in self._instances:
            params = self.params_by_condition.get(condition) or next(iter(self.params_by_condition.values()), {})
            inst = self.plugin_cls(params=params)
            self._memory_keys[key] = tuple(
                k for k, v in vars(inst).items() if v is None or (isinstance(v, list | dict | set) and not v)
            )
            self._instances[key] = inst
            if not self._instances.keys() - {key}:  # later instances inherit the traits as memory
                self._begin_session(inst)
        inst = self._instances[key]
        prev = self._active
        if prev is not None and prev is not inst:
            for k in self._memory_keys[key]:
                if hasattr(prev, k):
                    setattr(inst, k, getattr(prev, k))
        return inst

    def begin_trial(self, info: TrialInfo, rng: np.random.Generator) -> None:
        inst = self.instance_for(info.condition)
        self._active = inst
        inst.begin_trial(info, rng)

    def act(self, t: float, percept: Mapping[str, Any]) -> Action:
        if self._active is None:
            raise ModelParameterError("population participant: act() before begin_trial()")
        return self._active.act(t, percept)

    def answer(self, item: Mapping[str, Any], rng: np.random.Generator) -> int:
        condition = item.get("condition") if isinstance(item, Mapping) else None
        if isinstance(condition, str) and condition in self.params_by_condition:
            inst = self.instance_for(condition)
            self._active = inst
        else:
            inst = self._active or self.instance_for(next(iter(self.params_by_condition), ""))
        return inst.answer(item, rng)
