"""Write the studentized-range spline tables that ship in the wheel.

``python -m studyctl.stats.studentized_range_tables [--k-max K]`` recomputes log P(R > w) by quadrature for
k = 3…K on the module's grid and stores the quintic spline coefficients next to
:mod:`studyctl.stats.studentized_range` (a few hundred KB). A test rebuilds some of them and compares,
so a change of the grid or the quadrature that is not followed by a rewrite is caught.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np

from . import studentized_range as sr

K_MAX = 20  # Tukey comparisons of up to 20 groups start without building a table


def write_tables(k_max: int = K_MAX, path: Path | None = None) -> Path:
    path = path or Path(sr.__file__).with_name(sr.TABLE_FILE)
    ks = np.arange(3, k_max + 1)
    splines = [sr.build_range_table(int(k)) for k in ks]
    tmp = path.with_suffix(".tmp.npz")
    np.savez(
        tmp,
        knots=splines[0].t,
        # one member per k: a first Tukey call reads only its own 32 KB
        **{f"k{k}": s.c for k, s in zip(ks, splines, strict=True)},
        grid_spec=np.array([sr._W_MAX, sr._W_STEP, sr._SPLINE_DEGREE, sr._NZ], dtype=float),
    )
    os.replace(tmp, path)
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--k-max", type=int, default=K_MAX)
    print(write_tables(parser.parse_args().k_max))


if __name__ == "__main__":
    main()
