"""Virtual populations and published targets (issue 17): the shipped files and the code that reads them.

``<protocol>.yaml`` (``format: studyctl-population/1``) says how the protocol's virtual participants differ
from each other: traits drawn per person from the session's seeded stream, parameters fixed for everyone,
and the calibration that produced the numbers. ``<protocol>.targets.yaml`` (``format: studyctl-targets/1``)
holds the paper's published numbers a simulation is compared with. ``studyctl simulate``, ``demo`` and
``power`` use the shipped population of a protocol by default; ``studyctl calibrate`` fits one.
"""

from studyctl.populations.free import FreeParam, apply_values, free_params
from studyctl.populations.loader import (
    SHIPPED,
    check_population_for,
    describe_choice,
    load_population_file,
    parse_population,
    participant_params,
    population_for,
    resolve_population,
    shipped_population_path,
)
from studyctl.populations.model import FORMAT, Trait, TraitPopulation

__all__ = [
    "FORMAT",
    "SHIPPED",
    "FreeParam",
    "Trait",
    "TraitPopulation",
    "apply_values",
    "check_population_for",
    "describe_choice",
    "free_params",
    "load_population_file",
    "parse_population",
    "participant_params",
    "population_for",
    "resolve_population",
    "shipped_population_path",
]
