"""The tissue palpator's local baselines (tissue_decision.local_medians) take every press's median of the survey
presses near it in one call instead of one ``np.nanmedian`` per press: the two must agree to the bit, ties, NaN
cues, infinities and presses with no finite neighbour (NaN) included."""

import warnings

import numpy as np

from studyctl.participants.tissue_decision import local_medians


def test_local_medians_equal_one_nanmedian_per_press():
    rng = np.random.default_rng(1)
    rows = 0
    for _ in range(300):
        n = int(rng.integers(5, 120))
        m = int(rng.integers(5, n + 1))
        sv = rng.normal(1.0, 0.3, m)
        if rng.random() < 0.5:
            sv = np.round(sv, 1)  # ties, so even counts take the mean of two equal or unequal middles
        sv[rng.random(m) < 0.2] = np.nan
        if rng.random() < 0.1:
            sv[rng.integers(m)] = np.inf
        near = rng.random((n, m)) < rng.random()
        near[0] = False  # a press with no survey press near it
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # "All-NaN slice encountered", in both
            per_press = np.array([np.nanmedian(np.where(near[i], sv, np.nan)) for i in range(n)])
            at_once = local_medians(sv, near)
        assert per_press.tobytes() == at_once.tobytes()
        assert np.isnan(at_once[0])
        rows += n
    assert rows > 10_000
