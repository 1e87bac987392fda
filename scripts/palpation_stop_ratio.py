"""Can v5's ``stop_ratio`` act? Press by press, how far a felt cue gets above the running median of plain pressing
(what ``_strong`` compares with) while the press still descends, where a stop can happen, against the press's peak.

    python scripts/palpation_stop_ratio.py [TRIALS] [speeds=18.8717,12,8,4] [name=value ...]

The person is the shipped population's typical one (``familiarise`` on, every trait at its location; ``stop_ratio``
1.6), at each press speed given, trials 0..TRIALS-1 after practice with the trial's controller (the broken-controller
tests' scenes and seeds). Per controller: presses that ran with a median set, the largest cue/median ratio seen while
descending (the 95th percentile and the maximum over presses), the share of presses whose descending ratio reached
stop_ratio, presses a cue stopped, and the same ratio at the press's peak (the note the person judges by)."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from palpation.practice_support import trial_after_practice  # noqa: E402
from palpation_practice_decision import typical_person  # noqa: E402

from studyctl.controllers.bio_inspired import BioInspiredController  # noqa: E402
from studyctl.controllers.palpation import LinearController, PiecewiseController  # noqa: E402
from studyctl.participants.palpator import VirtualPalpator  # noqa: E402
from studyctl.participants.palpator_perception import STOP  # noqa: E402
from studyctl.participants.palpator_press import CHANNELS  # noqa: E402


class _Watched(VirtualPalpator):
    """The person as is, noting for each press the largest cue/median ratio that ``_strong`` was asked about (it is
    asked only while the press descends and the dent is seen) and, at the press's end, the peak's ratio."""

    def begin_trial(self, info, rng):
        super().begin_trial(info, rng)
        self.descending: dict[int, float] = {}
        self.peaks: list[tuple[float, float]] = []  # (largest descending ratio, peak ratio) per press with a median

    def _strong(self, percept, gain=1.0):
        seg = self._pressing
        if seg is not None and self._usual:
            r = max((percept[ch] / self._usual[ch] for ch in self._usual
                     if isinstance(percept.get(ch), int | float)), default=0.0)
            self.descending[id(seg)] = max(self.descending.get(id(seg), 0.0), r)
        return super()._strong(percept, gain)

    def _end_segment(self, seg):
        if seg.kind == "press" and self._usual and not self._practice:
            peak = max((self._notes.get((ch, "peak"), 0.0) / self._usual[ch] for ch in CHANNELS
                        if self._usual.get(ch, 0) > 0), default=0.0)
            self.peaks.append((self.descending.get(id(seg), 0.0), peak))
        super()._end_segment(seg)


def main(argv: list[str]) -> None:
    trials = int(argv[0]) if argv and "=" not in argv[0] else 24
    speeds = [18.8717, 12.0, 8.0, 4.0]
    overrides = []
    for a in argv:
        if a.startswith("speeds="):
            speeds = [float(v) for v in a.split("=", 1)[1].split(",")]
        elif "=" in a:
            overrides.append(a)
    t0 = time.process_time()
    print(f"typical v5 person, trials 0-{trials - 1}; overrides: {overrides or 'none'}")
    print("speed mm/s | controller | presses with a median | descending ratio p95 / max | share >= stop_ratio | "
          "presses stopped by a cue | peak ratio p95 / max | share of peaks >= stop_ratio")
    for speed in speeds:
        params = typical_person(overrides + [f"press_speed_mm_s={speed}"])
        ratio = params["stop_ratio"]
        for ctrl in (LinearController, PiecewiseController, BioInspiredController):
            rows, stops = [], 0
            for k in range(trials):
                person = _Watched(params)
                trial_after_practice(person, ctrl, k)
                rows += person.peaks
                stops += sum(ev.felt.get(STOP, 0) for ev in person.evidence.values())
            d = np.array([r[0] for r in rows]) if rows else np.zeros(1)
            p = np.array([r[1] for r in rows]) if rows else np.zeros(1)
            print(f"{speed:.1f} | {ctrl.name} | {len(rows)} | {np.percentile(d, 95):.2f} / {d.max():.2f} | "
                  f"{np.mean(d >= ratio):.3f} | {stops} | {np.percentile(p, 95):.2f} / {p.max():.2f} | "
                  f"{np.mean(p >= ratio):.3f}", flush=True)
    print(f"stop_ratio {ratio}; {time.process_time() - t0:.1f} s CPU")


if __name__ == "__main__":
    from script_usage import argv_or_usage

    main(argv_or_usage(__doc__))
