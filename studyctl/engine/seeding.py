"""Random streams of a session, derived from the session seed and the position in the plan.

Every Generator the engine hands out depends only on (session seed, plan step position, purpose), never
on how many numbers were drawn before. A resumed session, or a repeated trial, therefore sees exactly
the numbers an uninterrupted run would have seen at the same place in the plan.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

# Purpose tags keep the streams of one step independent of each other.
_SCENE, _PARTICIPANT, _DEVICE, _ANSWER, _REPLACEMENT, _PERSON, _POPULATION = 1, 2, 3, 4, 5, 6, 7


@dataclass(frozen=True)
class TrialStreams:
    """The three Generators of one trial: scene build, participant behaviour, device noise."""

    scene: np.random.Generator
    participant: np.random.Generator
    device: np.random.Generator


def _rng(seed: int, *key: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([int(seed) & 0xFFFFFFFFFFFFFFFF, *map(int, key)]))


def trial_streams(seed: int, position: int) -> TrialStreams:
    """Generators for the trial at plan step ``position`` (the same for every attempt at it)."""
    return TrialStreams(
        scene=_rng(seed, position, _SCENE),
        participant=_rng(seed, position, _PARTICIPANT),
        device=_rng(seed, position, _DEVICE),
    )


def person_rng(seed: int) -> np.random.Generator:
    """Generator for what a virtual participant draws once per session (its traits), handed to it at the start
    of every run of the session, so a resumed session's participant is the same person."""
    return _rng(seed, 0, _PERSON)


def population_rng(seed: int) -> np.random.Generator:
    """Generator for a virtual person's between-subject traits drawn from a population file
    (:meth:`studyctl.populations.TraitPopulation.draw`): one stream per session seed, so the same seeds give
    the same people whatever population values a calibration tries (common random numbers)."""
    return _rng(seed, 0, _POPULATION)


class _Drawing(Protocol):  # a TraitPopulation (studyctl.populations sits above the engine)
    def draw(self, rng: np.random.Generator, stratum: str | None = None) -> Mapping[str, Any]: ...


def person_traits(population: _Drawing, seed: int, stratum: str | None) -> Mapping[str, Any]:
    """The traits of the virtual person whose session seed is ``seed``: ``population``'s draw from that seed's
    population stream (:func:`population_rng`) in the person's stratum.

    The one rule for who a seed's person is: :func:`studyctl.engine.api.run_session` draws with it, and so do
    the callers that must hold the person while changing something else (a power replicate's knobs on top of
    the traits; ``bench simrate``'s yardstick, the same people run on other session seeds).
    """
    return population.draw(population_rng(seed), stratum)


def answer_rng(seed: int, position: int, item_number: int) -> np.random.Generator:
    """Generator for the answer to item ``item_number`` of the questionnaire at step ``position``."""
    return _rng(seed, position, _ANSWER, item_number)


def session_seed(study_seed: int, participant_code: str) -> int:
    """A default session seed from the study seed and the participant code (stable across machines)."""
    code = np.frombuffer(participant_code.encode("utf-8"), dtype=np.uint8).astype(np.uint32)
    ss = np.random.SeedSequence([int(study_seed) & 0xFFFFFFFFFFFFFFFF, *code.tolist()])
    return int(ss.generate_state(1, dtype=np.uint32)[0])
