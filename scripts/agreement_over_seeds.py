"""A population's agreement index per seed and pooled over seeds, from simulated reports of the same study.

Usage: ``python scripts/agreement_over_seeds.py DIR [DIR ...]``, each a report folder (``studyctl report ... -o DIR``)
holding ``agreement.csv``, one per simulation seed, all of one protocol and population at the paper's size.

Why: the demo's index (``reports/index.html``, ``studyctl bench calibration``) is one seed's, and at 12-25
simulated people a verdict or a band check flips with the seed while nothing changed (seed 002's U-test: p 0.040
at 2024, 0.09-0.22 at 7, 11, 12 and 99 with the same population). Counting each check over several seeds' targets
says which misses are the population's and which are one seed's draw. Each line gives, over every role's targets,
those agreeing on every check, the directions right, the verdicts reproduced and the values within their band, each
as count/applicable, with the same rules as the report's index (``summary_from_frame``); and, where the reports have
the replication column, of the verdicts with a published p and the values in a sampling band, how many passed
against how many a same-size replication of the paper itself would pass on average.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pandas as pd

from studyctl.calibration.agreement import checks_as_booleans, summary_from_frame

CHECKS = (("agree", "agree_fraction", "agree_n"), ("directions", "direction_fraction", "direction_n"),
          ("verdicts", "verdict_fraction", "verdict_n"), ("within band", "within_fraction", "within_n"))


def agreement_frame(report_dir: Path) -> pd.DataFrame:
    """One report's agreement table with its yes/no columns as booleans (None where a check does not apply)."""
    path = report_dir / "agreement.csv"
    if not path.is_file():
        raise SystemExit(f"Error: {path} not found; pass report folders written by `studyctl report -o DIR`.")
    return checks_as_booleans(pd.read_csv(path, keep_default_na=True))


def index_line(label: str, frame: pd.DataFrame) -> str:
    """``label  agree a/n  directions …`` over all targets of ``frame``."""
    s = summary_from_frame(frame)["all"]
    parts = []
    for name, frac, n in CHECKS:
        count = "-" if s[frac] is None else f"{round(s[frac] * s[n])}"
        parts.append(f"{name} {count}/{s[n]}")
    # what a same-size replication of the paper itself would pass, where the report could say (replication column)
    for name, key in (("verdicts", "verdict"), ("in band", "within")):
        if s.get(f"{key}_p_n"):
            parts.append(f"[{name} with a chance {s[f'{key}_p_reproduced']}/{s[f'{key}_p_n']}, "
                         f"replication {s[f'{key}_expected']:.1f}]")
    return f"{label:32s} " + "  ".join(parts)


def main(argv: list[str]) -> int:
    if not argv or "-h" in argv or "--help" in argv:
        print((__doc__ or "").strip())
        return 0 if argv else 2
    frames = []
    for d in map(Path, argv):
        frame = agreement_frame(d)
        frames.append(frame)
        print(index_line(str(d), frame))
    if len(frames) > 1:
        print(index_line(f"pooled over {len(frames)} seeds", pd.concat(frames, ignore_index=True)))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
