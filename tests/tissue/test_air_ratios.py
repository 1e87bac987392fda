"""The tissue palpator's R₀ (tissue_perception.AirRatios): the median of its air ticks' cursor-over-hand travel ratios,
kept sorted and merged as the buffers grow, must be ``np.median`` of all the ratios to the bit at every look, whenever
the looks fall, NaN, ties and swapped buffers included."""

import math
from array import array

import numpy as np

from studyctl.participants.tissue_perception import AirRatios


def _want(dc: array, dh: array) -> float:
    return float(np.median(np.frombuffer(dc) / np.frombuffer(dh)))


def test_each_look_is_numpys_median_of_every_ratio_so_far():
    rng = np.random.default_rng(5)
    for case in range(40):
        dc, dh, ratios = array("d"), array("d"), AirRatios()
        for _ in range(int(rng.integers(1, 60))):
            k = int(rng.integers(1, 400))
            c = rng.uniform(0.0, 2.0, k)
            if case % 3 == 1:
                c = np.round(c, 1)  # ties
            dc.extend(c.tolist())
            dh.extend(rng.uniform(1e-3, 2.0, k).tolist())
            got = ratios.median(dc, dh)
            assert got == _want(dc, dh) and math.copysign(1, got) == math.copysign(1, _want(dc, dh))
        dc.append(1.0)  # the buffers can still grow: no view of them is kept
        dh.append(1.0)


def test_a_nan_ratio_makes_the_median_nan_as_numpy_does():
    dc, dh, ratios = array("d", [1.0, 2.0, 3.0]), array("d", [1.0, 1.0, 1.0]), AirRatios()
    assert ratios.median(dc, dh) == 2.0
    dc.append(math.nan)
    dh.append(1.0)
    assert math.isnan(ratios.median(dc, dh)) and math.isnan(_want(dc, dh))


def test_new_buffers_start_over():
    ratios = AirRatios()
    assert ratios.median(array("d", [1.0, 5.0, 9.0]), array("d", [1.0] * 3)) == 5.0
    assert ratios.median(array("d", [2.0]), array("d", [1.0])) == 2.0
