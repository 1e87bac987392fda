"""Seeds of one replicate study, derived from the master seed and (sample size, replicate index) only.

Every random number of a replicate — the simulated study's master seed (schedules, tumour placements),
each participant's session seed (behaviour, device noise, answers) and the population's random
offsets — comes from ``SeedSequence(master, spawn_key=(participants, replicate))``. Nothing depends on
which worker runs the replicate or in what order, so a run on any number of workers equals a serial run.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from studyctl.errors import UsageError

SEED_LIMIT = 2**63
# Children of a replicate's SeedSequence, by purpose (their order is part of the results' definition).
_STUDY, _SESSIONS, _POPULATION = range(3)


def check_master_seed(seed: int) -> int:
    """The master seed as an int in [0, 2**63) (UsageError otherwise)."""
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or not 0 <= int(seed) < SEED_LIMIT:
        raise UsageError(f"--seed must be an integer in [0, 2**63), got {seed!r}")
    return int(seed)


def replicate_sequence(master_seed: int, participants: int, replicate: int) -> np.random.SeedSequence:
    """The SeedSequence of replicate ``replicate`` at sample size ``participants``."""
    return np.random.SeedSequence(check_master_seed(master_seed), spawn_key=(int(participants), int(replicate)))


@dataclass(frozen=True)
class ReplicateSeeds:
    """The seeds one replicate study uses.

    ``study_seed`` is the simulated study's master seed (stored with it: schedules and placements);
    ``session_seeds[i]`` the i-th enrolled participant's session seed; ``population`` seeds the
    Generator of the participants' random offsets.
    """

    study_seed: int
    session_seeds: tuple[int, ...]
    population: np.random.SeedSequence

    def population_rng(self) -> np.random.Generator:
        return np.random.default_rng(self.population)


def replicate_seeds(master_seed: int, participants: int, replicate: int) -> ReplicateSeeds:
    """Derive a replicate's seeds (see the module docs)."""
    return seeds_from(replicate_sequence(master_seed, participants, replicate), participants)


#: First spawn-key element of the two-stage design's streams (pool chunks, stage-2 draws); sample sizes are
#: positive, so these never collide with a replicate's (participants, replicate) key.
POOL_KEY, DRAW_KEY = -1, -2


def pool_seeds(master_seed: int, chunk_size: int, chunk: int) -> ReplicateSeeds:
    """Seeds of pool chunk ``chunk`` (a simulated study of ``chunk_size`` people) of the two-stage design."""
    seq = np.random.SeedSequence(check_master_seed(master_seed), spawn_key=(2**32 + POOL_KEY, chunk_size, chunk))
    return seeds_from(seq, chunk_size)


def draw_rng(master_seed: int, participants: int, replicate: int) -> np.random.Generator:
    """The Generator that picks stage-2 replicate ``replicate``'s people from the pool at size ``participants``."""
    key = (2**32 + DRAW_KEY, int(participants), int(replicate))
    return np.random.default_rng(np.random.SeedSequence(check_master_seed(master_seed), spawn_key=key))


def seeds_from(sequence: np.random.SeedSequence, participants: int) -> ReplicateSeeds:
    """A study's seeds from its SeedSequence (children: study, sessions, population — in that order)."""
    children = sequence.spawn(3)
    study_seed = int(children[_STUDY].generate_state(1, dtype=np.uint64)[0] >> np.uint64(1))
    sessions = tuple(int(s) for s in children[_SESSIONS].generate_state(int(participants), dtype=np.uint32))
    return ReplicateSeeds(study_seed, sessions, children[_POPULATION])
