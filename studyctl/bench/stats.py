"""``studyctl bench stats``: speed of studyctl.stats beside scipy/statsmodels on the same inputs."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np

from studyctl import stats
from studyctl.bench import BenchResult, time_calls


def _median_ms(fn, repeat: int) -> float:
    return float(np.median(time_calls(fn, repeat=repeat))) * 1e3


# A report's first Tukey call runs in a fresh process: time it there, CPU seconds of the call alone (imports
# excluded, they are the same libraries for both), for ours and scipy's on the same 5 × 12 groups.
_COLD_TUKEY = """
import json, sys, time
import numpy as np
rng = np.random.default_rng(12345)
g5 = [np.round(rng.normal(10 + 0.5 * i, 1.5, 12), 3) for i in range(5)]
if sys.argv[1] == "studyctl":
    from studyctl.stats import tukey_hsd
else:
    from scipy.stats import tukey_hsd
c0, w0 = time.process_time(), time.perf_counter()
tukey_hsd(*g5)
print(json.dumps({"cpu_ms": 1e3 * (time.process_time() - c0), "wall_ms": 1e3 * (time.perf_counter() - w0)}))
"""


def cold_tukey_ms(which: str, runs: int) -> dict[str, float]:
    """Median CPU and wall milliseconds of the first ``tukey_hsd`` call in ``runs`` fresh interpreters."""
    samples = [
        json.loads(subprocess.run([sys.executable, "-c", _COLD_TUKEY, which], capture_output=True, text=True,
                                  check=True).stdout)
        for _ in range(runs)
    ]
    return {key: float(np.median([s[key] for s in samples])) for key in ("cpu_ms", "wall_ms")}


def run(quick: bool = False) -> BenchResult:
    """Median wall time of each test on seed-sized and large data, with the peer on the same data."""
    import scipy.stats as sps
    from statsmodels.stats.multicomp import pairwise_tukeyhsd

    rng = np.random.default_rng(12345)
    rep = 5 if quick else 50
    rep_slow = 3 if quick else 9
    g5 = [np.round(rng.normal(10 + 0.5 * i, 1.5, 12), 3) for i in range(5)]
    g4 = [rng.normal(0.3 * i, 1, 25) for i in range(4)]
    x20, y20 = rng.normal(0, 1, 20), rng.normal(0.5, 1, 20)
    d20 = rng.normal(0.4, 1, 20)
    x200, y200 = rng.normal(0, 1, 200), rng.normal(0.1, 1, 200)
    xt, yt = rng.integers(1, 8, 50), rng.integers(1, 8, 50)
    dt = rng.integers(-3, 8, 40)
    figures: dict[str, float] = {}
    peers: dict[str, float] = {}

    figures["tukey_5x12_ms"] = _median_ms(lambda: stats.tukey_hsd(*g5), rep)
    peers["scipy_tukey_5x12_ms"] = _median_ms(lambda: sps.tukey_hsd(*g5), rep_slow)
    labels = np.repeat(np.arange(5), 12)
    peers["statsmodels_tukey_5x12_ms"] = _median_ms(lambda: pairwise_tukeyhsd(np.concatenate(g5), labels), rep_slow)
    figures["scipy_tukey_5x12_ms"] = peers["scipy_tukey_5x12_ms"]
    figures["tukey_speedup_vs_scipy"] = peers["scipy_tukey_5x12_ms"] / figures["tukey_5x12_ms"]

    runs = 3 if quick else 9
    ours_cold, scipy_cold = {}, {}
    for _ in range(runs):  # interleaved, so that load changes hit both alike
        for which, store in (("studyctl", ours_cold), ("scipy", scipy_cold)):
            for key, value in cold_tukey_ms(which, 1).items():
                store.setdefault(key, []).append(value)
    for key in ("cpu_ms", "wall_ms"):
        figures[f"tukey_5x12_cold_{key}"] = float(np.median(ours_cold[key]))
        peers[f"scipy_tukey_5x12_cold_{key}"] = float(np.median(scipy_cold[key]))
    figures["tukey_cold_speedup_vs_scipy_cpu"] = (
        peers["scipy_tukey_5x12_cold_cpu_ms"] / figures["tukey_5x12_cold_cpu_ms"])

    stats.rank_sum(x200, y200, method="exact")  # the table is cached per (m, n); cold time below
    from studyctl.stats import _exact

    def cold_200():
        _exact.rank_sum_lower_cdf.cache_clear()
        stats.rank_sum(x200, y200, method="exact")

    figures["rank_sum_exact_200x200_ms"] = _median_ms(cold_200, rep_slow)
    figures["rank_sum_exact_200x200_cached_ms"] = _median_ms(lambda: stats.rank_sum(x200, y200, method="exact"), rep)
    peers["scipy_mannwhitneyu_exact_200x200_ms"] = _median_ms(
        lambda: sps.mannwhitneyu(x200, y200, method="exact"), rep_slow)
    figures["rank_sum_exact_ties_50x50_ms"] = _median_ms(lambda: stats.rank_sum(xt, yt, method="exact"), rep_slow)
    peers["scipy_mannwhitneyu_permutation_ties_50x50_ms"] = _median_ms(
        lambda: sps.mannwhitneyu(xt, yt, method=sps.PermutationMethod(n_resamples=9999, random_state=1)), 3)

    def cold_sr():
        _exact.signed_rank_tied_cdf.cache_clear()
        stats.signed_rank(dt, method="exact")

    figures["signed_rank_exact_ties_n40_ms"] = _median_ms(cold_sr, rep)
    peers["scipy_wilcoxon_permutation_ties_n40_ms"] = _median_ms(
        lambda: sps.wilcoxon(dt, method=sps.PermutationMethod(n_resamples=9999, random_state=1)), 3)

    figures["kruskal_4x25_us"] = _median_ms(lambda: stats.kruskal_wallis(*g4), rep * 4) * 1e3
    peers["scipy_kruskal_4x25_us"] = _median_ms(lambda: sps.kruskal(*g4), rep * 4) * 1e3

    seed = {
        "rank_sum_20x20_ms": (lambda: stats.rank_sum(x20, y20), lambda: sps.mannwhitneyu(x20, y20)),
        "signed_rank_n20_ms": (lambda: stats.signed_rank(d20), lambda: sps.wilcoxon(d20)),
        "dunn_4x25_ms": (lambda: stats.dunn(*g4), None),
        "anova_5x12_ms": (lambda: stats.anova_oneway(*g5), lambda: sps.f_oneway(*g5)),
        "wilson_ms": (lambda: stats.wilson_interval(50, 60), None),
        "newcombe_ms": (lambda: stats.newcombe_interval(50, 60, 47, 60), None),
        "friedman_4x25_ms": (lambda: stats.friedman(*g4), lambda: sps.friedmanchisquare(*g4)),
        "signed_rank_critical_n20_ms": (lambda: stats.signed_rank_critical(20), None),
    }
    for key, (ours, peer) in seed.items():
        figures[key] = _median_ms(ours, rep * 2)
        if peer is not None:
            peers["scipy_" + key] = _median_ms(peer, rep)
    figures["studentized_range_sf_us"] = _median_ms(lambda: stats.studentized_range_sf(3.5, 5, 55), rep * 2) * 1e3
    peers["scipy_studentized_range_sf_us"] = _median_ms(lambda: sps.studentized_range.sf(3.5, 5, 55), rep_slow) * 1e3
    return BenchResult(
        name="stats",
        figures=figures,
        peers=peers,
        notes=[
            "median wall time of repeated calls after warm-up; peers run on the same inputs in the same run",
            "rank_sum_exact_200x200_ms clears the cached null table before every call (cold); *_cached_ms reuses it",
            "signed_rank_exact_ties_n40_ms clears its cache too; tukey_5x12_ms reuses the cached per-k range table",
            "tukey_5x12_cold_*: the first call in a fresh interpreter (median of interleaved runs, imports excluded); "
            "the per-k range table ships in the wheel, so no quadrature runs",
            "scipy's tied 'exact' peers are permutation tests (9 999 resamples): scipy has no exact conditional null",
        ],
    )
