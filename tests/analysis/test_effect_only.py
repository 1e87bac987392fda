"""The bootstrap's effect-size-only functions give the tests' effect sizes bit for bit (NaN where theirs is)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from studyctl.analysis import catalog
from studyctl.analysis.effect_ci import _EFFECT_ONLY, _HARMLESS, _effect_of
from studyctl.analysis.procedures import Cell


def _samples(rng: np.random.Generator, k: int, case: int, paired: bool) -> tuple[np.ndarray, ...]:
    sizes = np.full(k, rng.integers(2, 14)) if paired else rng.integers(2, 14, k)
    if case % 3 == 1 and paired and case % 2:  # every subject the same profile: no residual, RM-ANOVA's eta 1
        return tuple(np.full(n, float(i)) for i, n in enumerate(sizes))
    if case % 3 == 0:  # ties, as in rounded or count metrics
        return tuple(rng.integers(0, 4, n).astype(float) for n in sizes)
    if case % 3 == 1:  # every value the same: Kruskal-Wallis has no H, RM-ANOVA no F (NaN)
        return tuple(np.full(n, 2.5) for n in sizes)
    return tuple(rng.normal(10.0, 3.0, n) for n in sizes)


def _harmless_options(test: str, case: int) -> dict[str, object]:
    """No options, or (every other case) a combination of the values the effect-only path accepts."""
    harmless = _HARMLESS.get(test, {})
    if not harmless or case % 2:
        return {}
    return {key: values[case // 2 % len(values)] for key, values in harmless.items()}


@pytest.mark.parametrize("test", sorted(_EFFECT_ONLY))
def test_effect_only_equals_the_tests_effect_size_bit_for_bit(test):
    spec = catalog.TESTS[test]
    rng = np.random.default_rng(7)
    for case in range(300):
        k = 2 if spec.max_levels == 2 else int(rng.integers(2, 5))
        levels = tuple(f"L{i}" for i in range(k))
        options = _harmless_options(test, case)
        template = Cell(levels=levels, alpha=0.05, options=options, effect_size=None, compare="condition")
        samples = _samples(rng, k, case, spec.design == catalog.WITHIN)
        (finding,) = spec.run(Cell(levels=levels, alpha=0.05, options=options, effect_size=None, compare="condition",
                                   samples=samples))
        want = float(finding.summary.effect_size)
        got = _effect_of(spec, template)(samples)
        assert (math.isnan(want) and math.isnan(got)) or np.float64(got).tobytes() == np.float64(want).tobytes()


def test_an_option_that_could_change_the_outcome_runs_the_whole_test(monkeypatch):
    # the effect-only functions know no options: with one that might matter set, the bootstrap runs the test itself
    monkeypatch.setitem(_EFFECT_ONLY, "rank_sum", lambda *samples: 99.0)
    spec = catalog.TESTS["rank_sum"]
    samples = (np.array([1.0, 2.0, 5.0]), np.array([3.0, 4.0]))

    def effect(**options: object) -> float:
        return _effect_of(spec, Cell(levels=("a", "b"), alpha=0.05, options=options, effect_size=None,
                                     compare="condition"))(samples)

    assert effect() == 99.0
    assert effect(alternative="two-sided", method="auto") == 99.0  # seed 000's plan spells out the defaults
    assert effect(alternative="greater", continuity=False, method="asymptotic") == 99.0
    assert effect(method="exact") == (2.0 * 2.0 - 6.0) / 6.0  # U = 2 of 6, the test run whole
