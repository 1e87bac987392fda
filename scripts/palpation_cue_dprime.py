"""How much one press tells about each tumour class, per seed-000 feedback condition (an ideal-observer bound).

Usage: ``python scripts/palpation_cue_dprime.py [PRESSES] [DISC_HEIGHT_MM]`` (default 120 presses per spot and
condition; ~5 s CPU). DISC_HEIGHT_MM rebuilds the bio-inspired controller's CAPR model with its sensor disc that high
(the BHF code's, and the default, 5 mm: pressed past its height at F_crit = 2.1 N, after which every fingertip unit
gets an input); a counterfactual for diagnosis (50 mm puts F_crit at 21 N, beyond every press), not a setting.

Each press goes through the real sponge scene, the simulated forceps (sensor noise, ADC, instrument compliance,
actuator lags) and the condition's controller at 50 Hz, on plain sponge and on the soft, medium and hard tumour
(placed at holes 1-3, pressed at the hole centre with the palpator's 2 mm aim scatter), with the shipped
population's press spread at its trait locations: intended depth 5.3 mm x (1 + 0.08 N(0, 1)), speed lognormal
around 18.87 mm/s (log-SD 0.45, 2-20 mm/s), hold 0.094 s. The notes are the palpator's: balloon pressure and
vibration when the press passes 0.4/0.6/0.8/1.0 of its depth and at their peaks, and the camera's hand/tip depth
ratio. Printed: d' of tumour vs sponge by the linear discriminant of the log-notes (press-to-press covariance plus
the senses' Weber noise at the population's means: balloon 0.10, vibration 0.20, visual 0.06), and the best single
note's d'. A bound for a person who knows exactly how each cue moves (no learning error, no decision rule).
"""

from __future__ import annotations

import math
import sys

import numpy as np

from studyctl.controllers.bio_inspired import BioInspiredController
from studyctl.controllers.palpation import LinearController, NoFeedback, PiecewiseController
from studyctl.devices.palpation import SimulatedPalpationDevice
from studyctl.models import capr
from studyctl.models.perception import Sense
from studyctl.scenes.sponge import SpongePhantomScene

RATE_HZ = 50.0
CHECKPOINTS = (0.4, 0.6, 0.8, 1.0)
BALLOON, VIBRATION, VISUAL = Sense("b", 0.19, 0.10), Sense("v", 0.2, 0.20), Sense("view", 0.0, 0.06)


def press(scene, ctrl, rng, x, y, depth, speed, hold=0.094):
    """The log-notes of one press: balloon x 5, vibration x 5, camera yield."""
    dev = SimulatedPalpationDevice({}, scene=scene, rng=rng)
    dev.open()
    ctrl.reset()
    ramp = depth / speed
    notes: dict = {}
    peak_b = peak_v = 0.0
    ratio = None
    for k in range(int((2 * ramp + hold + 0.1) * RATE_HZ) + 2):
        t = k / RATE_HZ
        d = depth * min(t / ramp, 1.0) if t < ramp + hold else max(depth * (1 - (t - ramp - hold) / ramp), -1.0)
        dev.apply_input({"x_mm": x, "y_mm": y, "depth_mm": d})
        obs = dev.read(t)
        dev.write(ctrl.step(obs))
        fb = dev.feedback()
        peak_b, peak_v = max(peak_b, fb["balloon_psi"]), max(peak_v, fb["vibration_ms2"])
        for c in CHECKPOINTS:
            if c not in notes and d >= c * depth - 1e-9:
                notes[c] = (fb["balloon_psi"], fb["vibration_ms2"])
        if ratio is None and t >= ramp and obs.values["depth_mm"] > 0:
            ratio = depth / obs.values["depth_mm"]
    b = [max(notes[c][0], BALLOON.threshold) for c in CHECKPOINTS] + [max(peak_b, BALLOON.threshold)]
    v = [max(notes[c][1], VIBRATION.threshold) for c in CHECKPOINTS] + [max(peak_v, VIBRATION.threshold)]
    return np.log(b + v + [ratio])


def with_disc_height(ctrl: BioInspiredController, height_mm: float) -> BioInspiredController:
    """The controller with its CAPR model rebuilt for a sensor disc ``height_mm`` high (full populations)."""
    p = ctrl.params
    contact = capr.SkinContact(radius_mm=p["contact_radius_mm"], height_mm=height_mm)
    ctrl.model = capr.CaprModel([capr.build_population(capr.afferent_type(t), contact) for t in ctrl.afferent_types()],
                                input_rate_hz=p["rate_hz"], fs_model=p["fs_model"], window_s=p["window_s"],
                                activation_hz=p["activation_hz"])
    ctrl.reset()
    return ctrl


def main(n: int, disc_height_mm: float | None = None) -> None:
    rng = np.random.default_rng(7)
    scene = SpongePhantomScene.build({}, {"sites": {"soft": 1, "medium": 2, "hard": 3}}, frozenset(), rng)
    holes = scene.params["holes_mm"]
    spots = {"sponge": holes[6], "soft": holes[0], "medium": holes[1], "hard": holes[2]}
    noise = np.array([BALLOON.sigma] * 5 + [VIBRATION.sigma] * 5 + [VISUAL.sigma]) ** 2
    for ctrl_cls in (NoFeedback, PiecewiseController, LinearController, BioInspiredController):
        ctrl = ctrl_cls({})
        if disc_height_mm is not None and isinstance(ctrl, BioInspiredController):
            ctrl = with_disc_height(ctrl, disc_height_mm)
            print(f"(bio_inspired: CAPR disc {disc_height_mm:g} mm, F_crit "
                  f"{min(q.force_crit_n for q in ctrl.model.populations):.3f} N)")
        data = {}
        for spot, (x, y) in spots.items():
            rows = []
            for _ in range(n):
                depth = 5.3 * max(1 + 0.08 * rng.standard_normal(), 0.05)
                speed = min(max(18.87 * math.exp(0.45 * rng.standard_normal()), 2.0), 20.0)
                rows.append(press(scene, ctrl, rng, x + 2 * rng.standard_normal(), y + 2 * rng.standard_normal(),
                                  depth, speed))
            data[spot] = np.array(rows)
        keys = slice(10, 11) if ctrl_cls is NoFeedback else slice(0, 11)  # without feedback only the camera
        out = []
        for spot in ("soft", "medium", "hard"):
            a, b = data[spot][:, keys], data["sponge"][:, keys]
            cov = np.atleast_2d(0.5 * (np.cov(a.T) + np.cov(b.T))) + np.diag(noise[keys])
            dmu = a.mean(0) - b.mean(0)
            d_lda = math.sqrt(max(float(dmu @ np.linalg.solve(cov, dmu)), 0.0))
            single = float((dmu / np.sqrt(np.diag(cov))).max())
            out.append(f"{spot} d' {d_lda:4.2f} (best note {single:4.2f})")
        print(f"{ctrl_cls.name:13s} " + "  ".join(out), flush=True)


if __name__ == "__main__":
    from script_usage import argv_or_usage

    argv_or_usage(__doc__)
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 120, float(sys.argv[2]) if len(sys.argv) > 2 else None)
