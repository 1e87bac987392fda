"""A virtual population: which traits of a participant kind vary between people, and how.

A population file (``format: studyctl-population/1``, see the package docs) names the protocol and the
participant plugin it is for, the traits drawn once per virtual person (distribution, location, spread,
range, per-stratum locations) and parameters fixed for everyone. :class:`TraitPopulation` is the checked,
immutable form; :meth:`TraitPopulation.draw` turns one seeded Generator into one person's traits.

Draws use one standard normal per trait, in sorted trait order, whatever the distribution (a ``fixed`` trait
still consumes its number). Two populations with the same trait names therefore give the same person the
same standard normals: changing a location or spread moves every person smoothly (common random numbers,
which calibration relies on). A trait marked ``appended`` takes its number after all the others (appended ones
in sorted order among themselves): a population that adds a trait that way gives every person the numbers, and
so the other traits, it had before, where a new name sorted in among the old ones would shift the later traits'
numbers and swap the people a comparison of the two populations pairs.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from studyctl.suggest import named

FORMAT = "studyctl-population/1"
DISTS = ("normal", "lognormal", "logitnormal", "fixed")
SOURCE_PREFIXES = ("CITED:", "CHOSEN:", "FITTED")


def _frozen(mapping: Mapping[str, Any]) -> dict[str, Any]:
    # a plain copy (picklable for Dask workers); the dataclasses are frozen and never hand it out to mutate
    return dict(mapping)


def _logit(p: float) -> float:
    return math.log(p / (1.0 - p))


def _expit(x: float) -> float:
    return 1.0 / (1.0 + math.exp(-x))


@dataclass(frozen=True)
class Trait:
    """One between-subject trait: ``value = transform(location + sd · z)`` clipped to ``[low, high]``.

    ``mean`` is the mean (normal), the median (lognormal), the median proportion (logitnormal) or the value
    (fixed); ``sd`` is in the unit (normal) or on the log / logit scale. ``groups`` maps a stratum id to the
    keys it overrides (``mean`` and/or ``sd``).
    """

    name: str
    dist: str
    mean: float
    sd: float
    low: float
    high: float
    unit: str = ""
    source: str = ""
    groups: Mapping[str, Mapping[str, float]] = field(default_factory=dict)
    integer: bool = False
    appended: bool = False  # drawn after the other traits (see the module docs)

    def __post_init__(self) -> None:
        object.__setattr__(self, "groups", _frozen({g: _frozen(v) for g, v in self.groups.items()}))

    def location(self, stratum: str | None) -> float:
        return float(self.groups.get(stratum or "", {}).get("mean", self.mean))

    def spread(self, stratum: str | None) -> float:
        return float(self.groups.get(stratum or "", {}).get("sd", self.sd))

    def value(self, z: float, stratum: str | None = None) -> float:
        """The trait of a person whose standard normal is ``z`` (clipped to the range)."""
        loc, sd = self.location(stratum), self.spread(stratum)
        if self.dist == "fixed":
            v = loc
        elif self.dist == "normal":
            v = loc + sd * z
        elif self.dist == "lognormal":
            v = loc * math.exp(sd * z)
        else:  # logitnormal
            v = _expit(_logit(loc) + sd * z)
        v = min(max(v, self.low), self.high)
        return float(round(v)) if self.integer else float(v)

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"dist": self.dist, "mean": self.mean}
        if self.dist != "fixed":
            out["sd"] = self.sd
        out["range"] = [self.low, self.high]
        if self.unit:
            out["unit"] = self.unit
        out["source"] = self.source
        if self.groups:
            out["groups"] = {g: dict(v) for g, v in self.groups.items()}
        if self.appended:
            out["appended"] = True
        return out


@dataclass(frozen=True)
class TraitPopulation:
    """A checked population file (see :func:`studyctl.populations.load_population_file`).

    ``sha256`` is the digest of the file's exact bytes (of the written text for a population made in
    memory, e.g. a calibration candidate); it is stored with every simulated session that used it.
    """

    name: str
    version: int
    protocol: str
    participant: str
    traits: tuple[Trait, ...]
    fixed: Mapping[str, Any] = field(default_factory=dict)
    calibration: Mapping[str, Any] = field(default_factory=dict)
    description: str = ""
    path: str = ""
    sha256: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "fixed", _frozen(self.fixed))
        object.__setattr__(self, "calibration", _frozen(self.calibration))
        object.__setattr__(self, "traits", tuple(sorted(self.traits, key=lambda t: t.name)))
        if not self.sha256:
            object.__setattr__(self, "sha256", hashlib.sha256(self.to_yaml().encode("utf-8")).hexdigest())

    @property
    def label(self) -> str:
        """``name v<version> (sha256 <12 hex>)`` for messages."""
        return f"{self.name} v{self.version} (sha256 {self.sha256[:12]})"

    def trait(self, name: str) -> Trait:
        return named(self.traits, name, what="trait", plural="traits", key="name",
                     where=f" in population {self.name!r}")

    def draw(self, rng: np.random.Generator, stratum: str | None = None) -> dict[str, float]:
        """One person's traits: one standard normal per trait in sorted name order, ``appended`` traits last
        (see module docs)."""
        order = [t for t in self.traits if not t.appended] + [t for t in self.traits if t.appended]
        z = rng.standard_normal(len(order))
        drawn = {t.name: t.value(float(zi), stratum) for t, zi in zip(order, z, strict=True)}
        return {t.name: drawn[t.name] for t in self.traits}

    def params(self, traits: Mapping[str, Any]) -> dict[str, Any]:
        """The participant's constructor params for a person with ``traits`` (fixed ones, then the traits)."""
        return {**self.fixed, **traits}

    def record(self, traits: Mapping[str, Any], stratum: str | None = None) -> dict[str, Any]:
        """What is stored with a session: which population (name, version, sha256, file) and this person."""
        return {
            "name": self.name,
            "version": self.version,
            "sha256": self.sha256,
            "file": self.path,
            "participant": self.participant,
            "stratum": stratum,
            "traits": {k: float(v) for k, v in sorted(traits.items())},
            "fixed": {k: (list(v) if isinstance(v, tuple) else v) for k, v in sorted(self.fixed.items())},
        }

    # -- editing (calibration) ------------------------------------------------------------------------
    def with_trait(self, name: str, **changes: Any) -> TraitPopulation:
        traits = tuple(replace(t, **changes) if t.name == name else t for t in self.traits)
        return replace(self, traits=traits, sha256="", path="")

    def with_values(self, values: Mapping[str, float]) -> TraitPopulation:
        """A copy with free parameters set (names as in :func:`studyctl.populations.free_param`)."""
        from studyctl.populations.free import apply_values

        return apply_values(self, values)

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "format": FORMAT,
            "name": self.name,
            "version": self.version,
            "protocol": self.protocol,
            "participant": self.participant,
        }
        if self.description:
            out["description"] = self.description
        out["traits"] = {t.name: t.to_dict() for t in self.traits}
        out["fixed"] = {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.fixed.items()}
        if self.calibration:
            out["calibration"] = _plain(self.calibration)
        return out

    def to_yaml(self) -> str:
        import yaml

        class _Dumper(yaml.SafeDumper):
            pass

        def short_list(dumper: yaml.SafeDumper, data: list) -> yaml.Node:
            flow = len(data) <= 4 and all(isinstance(v, int | float | str) for v in data)
            return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flow)

        def number(dumper: yaml.SafeDumper, data: float) -> yaml.Node:
            return dumper.represent_float(float(f"{data:.6g}"))  # fitted values: 6 significant digits

        _Dumper.add_representer(list, short_list)
        _Dumper.add_representer(float, number)
        return yaml.dump(self.to_dict(), Dumper=_Dumper, sort_keys=False, allow_unicode=True, width=110)


def _plain(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def check_source(source: str) -> bool:
    return any(str(source).startswith(p) for p in SOURCE_PREFIXES)

