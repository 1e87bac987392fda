"""Power analysis by simulation: replicate studies of virtual participants through the real engine.

For each sample size, ``replicates`` studies are simulated (enrollment, whole sessions through the
session engine, controllers, simulated devices and scenes, into throwaway in-memory databases), the
analysis plan runs on each, and the fraction of replicates in which each test is significant is the
power (with a Wilson interval), beside the distribution of the effect sizes. Replicates are independent
tasks seeded from ``SeedSequence(seed, spawn_key=(sample size, replicate))``: serially, on a local Dask
cluster or on an existing Dask scheduler the results are identical.

Public API:

* :func:`prepare_power` → :class:`PowerSpec` (every input checked before any work);
* :func:`studyctl.workflows.power.run_power` → :class:`~studyctl.workflows.power.PowerRun` (resumable; writes
  the report folder and its power-curve figure);
* :func:`simulate_replicate` → :class:`ReplicateResult` (one replicate study; the Dask task);
* :class:`Population`, :func:`load_population`, :func:`population_model` — the stated population;
* :func:`summarise` → :class:`PowerTable`; :func:`replicate_seeds`.
"""

from studyctl.power.population import Population, PopulationParticipant, load_population, population_model
from studyctl.power.replicate import ReplicateResult, simulate_replicate
from studyctl.power.seeds import replicate_seeds
from studyctl.power.spec import PowerSpec, prepare_power
from studyctl.power.summary import PowerTable, summarise

__all__ = [
    "Population",
    "PopulationParticipant",
    "PowerSpec",
    "PowerTable",
    "ReplicateResult",
    "load_population",
    "population_model",
    "prepare_power",
    "replicate_seeds",
    "simulate_replicate",
    "summarise",
]
