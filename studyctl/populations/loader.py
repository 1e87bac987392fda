"""Read and check a population file; every mistake is one error naming file:line:column and what to write.

Checks (before any simulation): the format tag; the participant plugin exists; every trait and fixed name is
a parameter that plugin declares (nearest name suggested); traits are real or whole-number parameters;
``dist`` is known; ``sd`` ≥ 0; the range is increasing, inside the parameter's declared range and holds the
location; lognormal locations > 0; logitnormal locations in (0, 1); ``source`` starts with CITED:, CHOSEN:
or FITTED; fixed values pass the plugin's own parameter check; the participant accepts the population's
typical person (every trait at its location).
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from studyctl.errors import ModelParameterError, NotFoundError, PluginError, PopulationError
from studyctl.populations.model import DISTS, FORMAT, SOURCE_PREFIXES, Trait, TraitPopulation, check_source
from studyctl.suggest import did_you_mean

TOP_KEYS = ("format", "name", "version", "protocol", "participant", "description", "traits", "fixed", "calibration")
TRAIT_KEYS = ("dist", "mean", "sd", "range", "unit", "source", "groups", "note", "appended")
GROUP_KEYS = ("mean", "sd")
CALIBRATION_KEYS = (
    "targets", "free", "used_for_fit", "validation", "bounds", "seed", "participants", "replicates",
    "objective", "evaluations", "estimates", "missed", "note", "fitted_at", "studyctl", "seconds", "cpu_seconds",
    "sim_rate_hz",
)


def participant_params(cls: type) -> dict[str, Any]:
    """``{name: Param}`` a participant plugin declares (class ``PARAMS`` or its module's ``PARAMS``)."""
    import sys

    spec = getattr(cls, "PARAMS", None) or getattr(sys.modules.get(cls.__module__), "PARAMS", None) or ()
    return {p.name: p for p in spec}


class _Checker:
    def __init__(self, marked: Any, label: str) -> None:
        self.m = marked
        self.label = label

    def fail(self, path: Sequence[Any], message: str, *, value: bool = True) -> PopulationError:
        mark = self.m.value_mark(tuple(path)) if value else self.m.key_mark(tuple(path))
        dotted = ".".join(str(p) for p in path) or "(top)"
        return PopulationError(f"{self.label}:{mark.line}:{mark.column}: {dotted}: {message}")

    def number(self, path: Sequence[Any], value: Any, what: str = "a number") -> float:
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(float(value)):
            raise self.fail(path, f"{value!r} is not {what}; write {what}")
        return float(value)


def load_population_file(path: str | Path, *, factory: Any | None = None) -> TraitPopulation:
    """Read and check a population YAML file (see the module docs for the checks).

    Raises
    ------
    NotFoundError
        No such file.
    PopulationError
        Anything wrong in it, as ``file:line:col: key.path: what; what to write``.
    """
    file = Path(path)
    if not file.is_file():
        raise NotFoundError(f"population file {str(path)!r} does not exist; give a studyctl-population/1 YAML file "
                            "(shipped ones: studyctl/populations/<protocol>.yaml)")
    from studyctl.inputs import read_text

    text = read_text(file, "population file", error=PopulationError)
    return parse_population(text, str(file), factory=factory,
                            sha256=hashlib.sha256(text.encode("utf-8")).hexdigest())


def parse_population(text: str, label: str, *, factory: Any | None = None, sha256: str = "") -> TraitPopulation:
    """Check population YAML ``text`` (``label`` names it in errors); see :func:`load_population_file`."""
    from studyctl.yamlmarks import load_marked

    marked = load_marked(text, label, merge_keys=False, text_keys=True)
    if marked.problems:
        raise PopulationError(str(marked.problems[0]))
    c = _Checker(marked, label)
    data = marked.data
    if not isinstance(data, Mapping):
        raise c.fail((), f"a population file is a mapping starting with 'format: {FORMAT}'")
    for key in data:
        if key not in TOP_KEYS:
            raise c.fail((key,), f"unknown key {key!r}{did_you_mean(key, TOP_KEYS)}; allowed: {', '.join(TOP_KEYS)}",
                         value=False)
    for key in ("format", "name", "version", "protocol", "participant", "traits"):
        if key not in data:
            raise c.fail((), f"missing key {key!r}; a population file has {', '.join(TOP_KEYS[:7])}")
    if data["format"] != FORMAT:
        raise c.fail(("format",), f"format {data['format']!r} is not supported; write 'format: {FORMAT}'")
    version = data["version"]
    if isinstance(version, bool) or not isinstance(version, int) or version < 1:
        raise c.fail(("version",), f"version {version!r} must be a whole number ≥ 1 (bump it when a number changes)")
    for key in ("name", "protocol", "participant"):
        if not isinstance(data[key], str) or not data[key].strip():
            raise c.fail((key,), f"{key} must be a non-empty name")

    from studyctl.engine.factory import EntryPointFactory

    factory = factory or EntryPointFactory()
    plugin = data["participant"]
    try:
        cls = factory.load("participant", plugin)
    except PluginError as exc:
        known = [n for n in factory.known("participant") if n != "person"]
        raise c.fail(("participant",), f"no participant plugin {plugin!r}{did_you_mean(plugin, known)}; "
                     f"known: {', '.join(known)} ({exc})") from None
    declared = participant_params(cls)
    if not declared:
        raise c.fail(("participant",), f"participant {plugin!r} declares no PARAMS; a population needs named params")

    traits_raw = data["traits"] or {}
    if not isinstance(traits_raw, Mapping):
        raise c.fail(("traits",), "traits must map parameter names to {dist, mean, sd, range, unit, source}")
    traits = [_trait(c, name, spec, declared, plugin) for name, spec in traits_raw.items()]

    fixed_raw = data.get("fixed") or {}
    if not isinstance(fixed_raw, Mapping):
        raise c.fail(("fixed",), "fixed must map parameter names to values")
    from studyctl.plugins.params import validate_params

    for name, value in fixed_raw.items():
        if name not in declared:
            raise c.fail(("fixed", name), f"{plugin} has no parameter {name!r}{did_you_mean(name, declared)}",
                         value=False)
        if name in traits_raw:
            raise c.fail(("fixed", name), f"{name!r} is both a trait and fixed; keep one", value=False)
        try:
            validate_params(plugin, {name: value}, declared.values())
        except ModelParameterError as exc:
            raise c.fail(("fixed", name), str(exc)) from None

    calibration = data.get("calibration") or {}
    if not isinstance(calibration, Mapping):
        raise c.fail(("calibration",), "calibration must be a mapping (targets, free, used_for_fit, validation …)")
    for key in calibration:
        if key not in CALIBRATION_KEYS:
            raise c.fail(("calibration", key), f"unknown key {key!r}{did_you_mean(key, CALIBRATION_KEYS)}; "
                         f"allowed: {', '.join(CALIBRATION_KEYS)}", value=False)

    pop = TraitPopulation(
        name=data["name"], version=int(version), protocol=data["protocol"], participant=plugin,
        traits=tuple(traits), fixed=dict(fixed_raw), calibration=dict(calibration),
        description=str(data.get("description") or ""), path=label, sha256=sha256,
    )
    typical = {t.name: t.value(0.0) for t in pop.traits}
    try:
        cls(params=pop.params(typical))
    except ModelParameterError as exc:
        raise c.fail(("traits",), f"{plugin} refuses the population's typical person (every trait at its "
                     f"location): {exc}", value=False) from None
    return pop


def _trait(c: _Checker, name: Any, spec: Any, declared: Mapping[str, Any], plugin: str) -> Trait:
    path = ("traits", name)
    if name not in declared:
        raise c.fail(path, f"{plugin} has no parameter {name!r}{did_you_mean(name, declared)}", value=False)
    param = declared[name]
    kind = getattr(param, "kind", float)
    if kind not in (float, int) or param.choices is not None:
        raise c.fail(path, f"{name!r} is a {kind.__name__} parameter; only real or whole-number parameters can "
                     "vary between people (put it under fixed:)", value=False)
    if not isinstance(spec, Mapping):
        raise c.fail(path, "a trait is a mapping {dist, mean, sd, range, unit, source}")
    for key in spec:
        if key not in TRAIT_KEYS:
            raise c.fail((*path, key), f"unknown key {key!r}{did_you_mean(key, TRAIT_KEYS)}; allowed: "
                         f"{', '.join(TRAIT_KEYS)}", value=False)
    dist = spec.get("dist")
    if dist not in DISTS:
        raise c.fail((*path, "dist"), f"unknown distribution {dist!r}{did_you_mean(dist, DISTS)}; allowed: "
                     f"{', '.join(DISTS)}")
    if "mean" not in spec:
        raise c.fail(path, "missing 'mean' (normal: mean; lognormal: median; logitnormal: median; fixed: value)")
    mean = c.number((*path, "mean"), spec["mean"])
    sd = 0.0
    if dist != "fixed":
        if "sd" not in spec:
            raise c.fail(path, f"missing 'sd' for a {dist} trait (the between-person spread)")
        sd = c.number((*path, "sd"), spec["sd"])
        if sd < 0:
            raise c.fail((*path, "sd"), f"sd = {sd:g} is negative; a spread is ≥ 0")
    p_low = -math.inf if param.low is None else float(param.low)
    p_high = math.inf if param.high is None else float(param.high)
    rng = spec.get("range")
    if rng is None:
        low, high = p_low, p_high
        if not (math.isfinite(low) and math.isfinite(high)) and dist != "fixed":
            raise c.fail(path, f"missing 'range: [low, high]' ({name} declares [{p_low:g}, {p_high:g}])")
    else:
        if not isinstance(rng, list) or len(rng) != 2:
            raise c.fail((*path, "range"), f"range must be [low, high], got {rng!r}")
        low = c.number((*path, "range", 0), rng[0])
        high = c.number((*path, "range", 1), rng[1])
        if not low < high:
            raise c.fail((*path, "range"), f"range [{low:g}, {high:g}] must have low < high")
        if low < p_low or high > p_high:
            raise c.fail((*path, "range"), f"range [{low:g}, {high:g}] leaves {plugin}'s allowed range for {name} "
                         f"[{p_low:g}, {p_high:g}]; narrow it")
    if dist == "lognormal" and not low > 0 and mean <= 0:
        raise c.fail((*path, "mean"), f"a lognormal median must be > 0, got {mean:g}")
    if dist == "logitnormal" and not (low >= 0 and high <= 1):
        raise c.fail((*path, "range"), f"a logitnormal trait is a proportion; its range must lie in [0, 1], "
                     f"got [{low:g}, {high:g}]")
    source = str(spec.get("source") or "")
    if not check_source(source):
        raise c.fail((*path, "source"), f"source {source!r} must start with {', '.join(SOURCE_PREFIXES)} (say where "
                     "the number comes from, why it was chosen, or that calibrate fitted it)")
    groups_raw = spec.get("groups") or {}
    if not isinstance(groups_raw, Mapping):
        raise c.fail((*path, "groups"), "groups must map a stratum id to {mean: …, sd: …}")
    groups: dict[str, dict[str, float]] = {}
    for g, gspec in groups_raw.items():
        if not isinstance(gspec, Mapping) or not gspec:
            raise c.fail((*path, "groups", g), "a group entry is {mean: …} and/or {sd: …}")
        for key, value in gspec.items():
            if key not in GROUP_KEYS:
                raise c.fail((*path, "groups", g, key), f"unknown key {key!r}{did_you_mean(key, GROUP_KEYS)}; "
                             "allowed: mean, sd", value=False)
            number = c.number((*path, "groups", g, key), value)
            if key == "sd" and number < 0:
                raise c.fail((*path, "groups", g, key), f"sd = {number:g} is negative; a spread is ≥ 0")
        groups[str(g)] = {k: float(v) for k, v in gspec.items()}
    for where, loc in [((*path, "mean"), mean)] + [((*path, "groups", g, "mean"), v["mean"])
                                                    for g, v in groups.items() if "mean" in v]:
        if not low <= loc <= high:
            raise c.fail(where, f"location {loc:g} is outside the trait's range [{low:g}, {high:g}]")
        if dist == "lognormal" and loc <= 0:
            raise c.fail(where, f"a lognormal median must be > 0, got {loc:g}")
        if dist == "logitnormal" and not 0 < loc < 1:
            raise c.fail(where, f"a logitnormal median must be a proportion in (0, 1), got {loc:g}")
    appended = spec.get("appended", False)
    if not isinstance(appended, bool):
        raise c.fail((*path, "appended"), f"appended must be true or false, got {appended!r}; write appended: true "
                     "to draw this trait after the others (a trait added to an existing population)")
    return Trait(name=str(name), dist=str(dist), mean=mean, sd=sd, low=low, high=high,
                 unit=str(spec.get("unit") or param.unit or ""), source=source, groups=groups,
                 integer=kind is int, appended=appended)


def check_population_for(pop: TraitPopulation, protocol: Any) -> None:
    """Raise PopulationError unless ``pop`` fits ``protocol``: the same participant kind and known strata."""
    ref = protocol.participants.virtual
    plugin = getattr(ref, "plugin", None)
    pid = protocol.study.id
    if plugin is None:
        raise PopulationError(f"population {pop.label} is for {pop.participant}, but protocol {pid!r} names no "
                              "virtual participant (participants.virtual)")
    if plugin != pop.participant:
        raise PopulationError(
            f"population {pop.path or pop.name} is for participant {pop.participant!r}, but protocol {pid!r} "
            f"simulates {plugin!r}; give a population file written for {plugin} (participant: {plugin})"
        )
    strata = list(protocol.stratum_ids)
    for t in pop.traits:
        for g in t.groups:
            if g not in strata:
                raise PopulationError(
                    f"population {pop.path or pop.name}: traits.{t.name}.groups: protocol {pid!r} has no stratum "
                    f"{g!r}{did_you_mean(g, strata)}; its strata: {', '.join(strata)}"
                )


def shipped_population_path(protocol_id: str) -> Path | None:
    """The population shipped for a protocol (``studyctl/populations/<id>.yaml``), or None."""
    here = Path(__file__).resolve().parent / f"{protocol_id}.yaml"
    return here if here.is_file() else None


def resolve_population(protocol: Any, population: str | Path | None, *, factory: Any | None = None
                       ) -> TraitPopulation | None:
    """The population a simulation of ``protocol`` uses: ``population`` (a file) if given, else the one shipped
    for the protocol, else None (the participant's own defaults). Checked against the protocol."""
    if population is not None:
        pop = load_population_file(population, factory=factory)
    else:
        path = shipped_population_path(protocol.study.id)
        if path is None:
            return None
        pop = load_population_file(path, factory=factory)
    check_population_for(pop, protocol)
    return pop


#: ``population=SHIPPED``: the protocol's shipped population (studyctl/populations/<protocol>.yaml) if any.
SHIPPED = "shipped"


def population_for(protocol: Any, population: Any, *, factory: Any | None = None) -> TraitPopulation | None:
    """The population a simulation of ``protocol`` draws its people from, checked against the protocol:
    a :class:`TraitPopulation` or a population file as given, :data:`SHIPPED` for the protocol's shipped one
    (None when it has none), None for the participant's own defaults."""
    if population is None:
        return None
    if isinstance(population, TraitPopulation):
        check_population_for(population, protocol)
        return population
    return resolve_population(protocol, None if population == SHIPPED else population, factory=factory)


def describe_choice(pop: TraitPopulation | None, protocol_id: str, explicit: bool) -> str:
    """One line for the CLI: which population a simulation uses (name, version, sha256 prefix), or none."""
    if pop is None:
        return (f"population: none shipped for {protocol_id}; virtual participants use their default parameters "
                "(all alike apart from their own trait noise); pass --population FILE to give one")
    how = "given" if explicit else "shipped"
    if pop.calibration.get("objective"):  # written by studyctl calibrate (a hand-made block has no objective)
        how += f", fitted to {pop.calibration.get('targets', 'targets')}"
    return f"population: {pop.name} v{pop.version} ({how}; sha256 {pop.sha256[:12]}; {len(pop.traits)} traits)"


__all__ = [
    "SHIPPED",
    "population_for",
    "check_population_for",
    "describe_choice",
    "load_population_file",
    "parse_population",
    "participant_params",
    "resolve_population",
    "shipped_population_path",
]
