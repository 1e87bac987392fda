"""Should a candidate population replace the shipped one? The landing rule, over several seeds.

Usage: ``python scripts/compare_populations.py --base R1 R2 R3 --candidate C1 C2 C3``, each argument a report
folder (``studyctl report ... -o DIR``) holding ``agreement.csv``; base and candidate folders are paired in order,
one pair per simulation seed, both at the paper's size.

Why summed squared z and several seeds: at 12-25 simulated people a target's agree/disagree flips with the seed
(stop 28 saw validation counts move by 3 of 20 between seeds 2024 and 99 with nothing changed), so counting
agreeing targets at one or two seeds cannot tell a better population from a luckier one. The summed squared z over
the fit targets is what ``studyctl calibrate`` minimises (see ``studyctl.calibration.agreement``); summing it over
seeds averages the seed noise out. The rule printed at the end:

* fit: summed fit z² over all seeds is lower for the candidate;
* validation: summed validation z² over all seeds is not higher, and the validation targets that agree on every
  check, counted over all seeds, are not fewer.

A z the report could not compute counts as the calibration's missing-target penalty (25, a 5 sigma miss).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import pandas as pd

from studyctl.calibration.agreement import MISSING_PENALTY

ROLES = ("fit", "validation")


def figures(report_dir: Path) -> dict[str, dict[str, float]]:
    """Per role: targets, targets agreeing on every check, summed squared z."""
    path = report_dir / "agreement.csv"
    if not path.is_file():
        raise SystemExit(f"Error: {path} not found; pass report folders written by `studyctl report -o DIR`.")
    frame = pd.read_csv(path)
    out: dict[str, dict[str, float]] = {}
    for role in ROLES:
        rows = frame[frame["role"] == role]
        z = pd.to_numeric(rows["z"], errors="coerce")
        z2 = sum(MISSING_PENALTY if not math.isfinite(v) else v * v for v in z)
        agrees = rows["agrees"].astype(str).str.lower().eq("true").sum()
        out[role] = {"targets": len(rows), "agree": int(agrees), "z2": float(z2)}
    return out


def _line(label: str, f: dict[str, dict[str, float]]) -> str:
    return "  ".join(
        f"{role} {f[role]['agree']:.0f}/{f[role]['targets']:.0f} z2 {f[role]['z2']:7.1f}" for role in ROLES
    ) + f"  {label}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", nargs="+", type=Path, required=True)
    ap.add_argument("--candidate", nargs="+", type=Path, required=True)
    args = ap.parse_args(argv)
    if len(args.base) != len(args.candidate):
        raise SystemExit(f"Error: {len(args.base)} base folders but {len(args.candidate)} candidate folders; "
                         "pass one of each per seed, in the same order.")
    totals = {side: {role: {"agree": 0.0, "z2": 0.0, "targets": 0.0} for role in ROLES}
              for side in ("base", "candidate")}
    for b, c in zip(args.base, args.candidate, strict=True):
        for side, d in (("base", b), ("candidate", c)):
            f = figures(d)
            print(_line(f"{side:9s} {d}", f))
            for role in ROLES:
                for k in ("agree", "z2", "targets"):
                    totals[side][role][k] += f[role][k]
    print()
    for side in ("base", "candidate"):
        print(_line(f"{side} (all seeds)", totals[side]))
    fit_better = totals["candidate"]["fit"]["z2"] < totals["base"]["fit"]["z2"]
    val_ok = (totals["candidate"]["validation"]["z2"] <= totals["base"]["validation"]["z2"]
              and totals["candidate"]["validation"]["agree"] >= totals["base"]["validation"]["agree"])
    print(f"\nfit z2 lower: {fit_better}; validation not worse (z2 and agreeing targets): {val_ok}; "
          f"ship: {fit_better and val_ok}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
