"""The stimulus chain of one seed-000 press, per tumour class and per feedback condition, on the shipped scene.

Usage: ``python scripts/palpation_stimulus_chain.py [PRESSES] [DEPTH_MM]`` (default 40 presses per spot at the
shipped population's intended depth 5.3 mm; ~10 s CPU). A smaller DEPTH_MM shows the same chain for lighter presses
(a diagnosis of where the maps saturate, not a population: the shipped depth is FITTED).

Each press is the one ``palpation_cue_dprime.py`` makes (the shipped population's press at its trait means with
its spread: depth 5.3 mm x (1 + 0.08 N(0, 1)), speed lognormal around 18.87 mm/s, log-SD 0.45, 2-20 mm/s, hold
0.094 s, the 2 mm aim scatter around the hole centre), through the real sponge scene and the simulated forceps
(instrument compliance, sensor noise, 10-bit ADC) at 50 Hz. Along the chain it prints, for plain sponge and the
soft, medium and hard tumour:

1. the scene: the column stiffness ratio at the hole centre and the peak force the sensor reports (N), the
   tip's depth (mm) and the force's peak rate (N/s);
2. the CAPR population (the bio-inspired controller's model of the same forces): peak activated-mean SA1, RA1
   and PC rates (Hz) and the eq. 3 / eq. 4 intensities;
3. per controller, the commanded control amounts' peaks (balloon %, vibration %), the delivered balloon pressure
   (psi) and vibration (Hz, m/s2) at the peak, and how many ticks the command sat at its cap (99) during the press;
4. each controller's commands for noiseless force trapezoids (where each map saturates), and 5. the CAPR
   population's activated-mean rates and activated-unit counts across the force at which its sensor disc is pressed
   past its height (the BHF code's 5 mm probe: beyond it the whole fingertip population is recruited).

Each cell is the mean over the presses; the ``d'`` columns are (tumour - sponge) / pooled SD over presses for the
peak force and for each controller's peak commands, on the log scale the senses use. This measures the stimulus,
not a person: no sense noise, no learning.
"""

from __future__ import annotations

import math
import sys

import numpy as np

from studyctl.controllers.bio_inspired import BioInspiredController
from studyctl.controllers.palpation import LinearController, NoFeedback, PiecewiseController
from studyctl.devices.palpation import SimulatedPalpationDevice
from studyctl.plugins.interfaces import Observation
from studyctl.scenes.sponge import SpongePhantomScene

RATE_HZ = 50.0
SPOTS = ("sponge", "soft", "medium", "hard")
CONTROLLERS = (NoFeedback, PiecewiseController, LinearController, BioInspiredController)


def press_trace(scene, ctrls, rng, x, y, depth, speed, hold=0.094):
    """One press driven through one device per controller (same forces, same sensor noise draws per device)."""
    ramp = depth / speed
    n = int((2 * ramp + hold + 0.1) * RATE_HZ) + 2
    seed = int(rng.integers(2**31))
    out = {}
    for ctrl in ctrls:
        dev = SimulatedPalpationDevice({}, scene=scene, rng=np.random.default_rng(seed))
        dev.open()
        ctrl.reset()
        rows = []
        for k in range(n):
            t = k / RATE_HZ
            d = depth * min(t / ramp, 1.0) if t < ramp + hold else max(depth * (1 - (t - ramp - hold) / ramp), -1.0)
            dev.apply_input({"x_mm": x, "y_mm": y, "depth_mm": d})
            obs = dev.read(t)
            cmd = ctrl.step(obs)
            dev.write(cmd)
            fb = dev.feedback()
            rates = getattr(ctrl, "last_rates", {})
            inten = getattr(ctrl, "last_intensity", {})
            rows.append((obs.values["force_n"], obs.values["depth_mm"], cmd["balloon_pct"], cmd["vibration_pct"],
                         fb["balloon_psi"], fb["vibration_hz"], fb["vibration_ms2"],
                         rates.get("SA1", 0.0), rates.get("RA1", 0.0), rates.get("PC", 0.0),
                         inten.get("force", 0.0), inten.get("vibration", 0.0)))
        out[ctrl.name] = np.array(rows)
    return out


def summarise(tr: np.ndarray) -> dict[str, float]:
    f, depth = tr[:, 0], tr[:, 1]
    k = int(np.argmax(f))
    return {
        "force": f.max(), "depth": depth.max(), "rate": float(np.max(np.diff(f)) * RATE_HZ),
        "bal": tr[:, 2].max(), "vib": tr[:, 3].max(), "psi": tr[:, 4].max(), "hz": tr[:, 5].max(),
        "ms2": tr[:, 6].max(), "psi_at_peak": tr[k, 4], "ms2_at_peak": tr[k, 6],
        "sa1": tr[:, 7].max(), "ra1": tr[:, 8].max(), "pc": tr[:, 9].max(),
        "ipf": tr[:, 10].max(), "ipv": tr[:, 11].max(),
        "capped": float(np.sum((tr[:, 2] >= 99.0) | (tr[:, 3] >= 99.0))),
    }


def dprime(a: np.ndarray, b: np.ndarray) -> float:
    """(a - b) / pooled SD on the log scale (0 when neither varies)."""
    la, lb = np.log(np.maximum(a, 1e-3)), np.log(np.maximum(b, 1e-3))
    sd = math.sqrt(0.5 * (la.var(ddof=1) + lb.var(ddof=1)))
    diff = float(la.mean() - lb.mean())
    return 0.0 if sd == 0.0 and diff == 0.0 else (diff / sd if sd > 0 else math.copysign(math.inf, diff))


def force_sweep(ctrls, levels=(0.5, 1.0, 1.5, 1.75, 2.0, 2.1, 2.2, 2.3, 2.5, 2.75, 3.0, 3.5),
                ramp_n_s=8.0, hold_s=1.0):
    """Each controller's commands for a noiseless trapezoid of force straight into it: peak while pressing and the
    value at the end of a 1 s hold, per plateau force (where each map saturates against the forces presses make)."""
    rows = []
    for level in levels:
        ramp = level / ramp_n_s
        row = [level]
        for ctrl in ctrls:
            ctrl.reset()
            peak_b = peak_v = 0.0
            for k in range(int((ramp + hold_s) * RATE_HZ) + 1):
                t = k / RATE_HZ
                cmd = ctrl.step(Observation(t, {"force_n": min(ramp_n_s * t, level)}))
                peak_b, peak_v = max(peak_b, cmd["balloon_pct"]), max(peak_v, cmd["vibration_pct"])
            row += [peak_b, peak_v, cmd["balloon_pct"], cmd["vibration_pct"]]
        rows.append(row)
    return rows


def main(n: int, depth_mm: float = 5.3) -> None:
    rng = np.random.default_rng(7)
    scene = SpongePhantomScene.build({}, {"sites": {"soft": 1, "medium": 2, "hard": 3}}, frozenset(), rng)
    holes = scene.params["holes_mm"]
    centre = {"sponge": holes[6], "soft": holes[0], "medium": holes[1], "hard": holes[2]}
    ratio = {"sponge": 1.0, **{t.cls: t.stiffness_ratio for t in scene.tumours}}
    ctrls = [cls({}) for cls in CONTROLLERS]
    data: dict[str, dict[str, list[dict[str, float]]]] = {s: {c.name: [] for c in ctrls} for s in SPOTS}
    for spot in SPOTS:
        x0, y0 = centre[spot]
        for _ in range(n):
            depth = depth_mm * max(1 + 0.08 * rng.standard_normal(), 0.05)
            speed = min(max(18.87 * math.exp(0.45 * rng.standard_normal()), 2.0), 20.0)
            x, y = x0 + 2 * rng.standard_normal(), y0 + 2 * rng.standard_normal()
            for name, tr in press_trace(scene, ctrls, rng, x, y, depth, speed).items():
                data[spot][name].append(summarise(tr))

    def col(spot, ctrl, key):
        return np.array([r[key] for r in data[spot][ctrl]])

    print(f"{n} presses per spot, intended depth {depth_mm} mm; mean over presses "
          "(d' vs sponge, log scale, pooled press-to-press SD)\n")
    print("1. scene + forceps (same for every controller)")
    print(f"{'spot':7s} {'column ratio':>12s} {'peak force N':>13s} {'d_force':>8s} {'tip depth mm':>13s} "
          f"{'peak dF/dt N/s':>15s} {'d_rate':>7s}")
    for spot in SPOTS:
        f, dep, r = (col(spot, "none", k) for k in ("force", "depth", "rate"))
        print(f"{spot:7s} {ratio[spot]:12.3f} {f.mean():13.3f} {dprime(f, col('sponge', 'none', 'force')):8.2f} "
              f"{dep.mean():13.2f} {r.mean():15.1f} {dprime(r, col('sponge', 'none', 'rate')):7.2f}")
    print("\n2. CAPR population (bio-inspired controller's model), peak activated-mean rates and eq. 3/4 intensities")
    print(f"{'spot':7s} {'SA1 Hz':>7s} {'d':>5s} {'RA1 Hz':>7s} {'d':>5s} {'PC Hz':>6s} {'I_pf':>6s} {'I_pv':>6s} "
          f"{'d':>5s}")
    for spot in SPOTS:
        g = {k: col(spot, "bio_inspired", k) for k in ("sa1", "ra1", "pc", "ipf", "ipv")}
        s = {k: col("sponge", "bio_inspired", k) for k in ("sa1", "ra1", "ipv")}
        print(f"{spot:7s} {g['sa1'].mean():7.1f} {dprime(g['sa1'], s['sa1']):5.2f} {g['ra1'].mean():7.1f} "
              f"{dprime(g['ra1'], s['ra1']):5.2f} {g['pc'].mean():6.1f} {g['ipf'].mean():6.2f} {g['ipv'].mean():6.2f} "
              f"{dprime(g['ipv'], s['ipv']):5.2f}")
    print("\n3. commands and delivered feedback per controller (peaks over the press; capped = ticks at 99)")
    print(f"{'controller':13s} {'spot':7s} {'balloon %':>9s} {'d':>5s} {'vib %':>6s} {'d':>5s} {'psi':>5s} "
          f"{'psi@Fmax':>8s} {'vib Hz':>6s} {'m/s2':>5s} {'m/s2@Fmax':>9s} {'capped':>6s}")
    for c in ctrls[1:]:
        for spot in SPOTS:
            b, v = col(spot, c.name, "bal"), col(spot, c.name, "vib")
            sb, sv = col("sponge", c.name, "bal"), col("sponge", c.name, "vib")
            vals = {k: col(spot, c.name, k).mean()
                    for k in ("psi", "psi_at_peak", "hz", "ms2", "ms2_at_peak", "capped")}
            db = "" if spot == "sponge" else f"{dprime(b, sb):5.2f}"
            dv = "" if spot == "sponge" else f"{dprime(v, sv):5.2f}"
            print(f"{c.name:13s} {spot:7s} {b.mean():9.1f} {db:>5s} {v.mean():6.1f} {dv:>5s} {vals['psi']:5.2f} "
                  f"{vals['psi_at_peak']:8.2f} {vals['hz']:6.0f} {vals['ms2']:5.2f} {vals['ms2_at_peak']:9.2f} "
                  f"{vals['capped']:6.1f}")
    print("\n4. commands for a noiseless force trapezoid (8 N/s up, 1 s hold), peak / end of hold, balloon|vibration %")
    head = "".join(f" {c.name:>23s}" for c in ctrls[1:])
    print(f"{'force N':>7s}{head}")
    for row in force_sweep(ctrls[1:]):
        cells = "".join(f" {row[1 + 4 * i]:5.1f}|{row[2 + 4 * i]:5.1f} {row[3 + 4 * i]:5.1f}|{row[4 + 4 * i]:5.1f}"
                        for i in range(3))
        print(f"{row[0]:7.2f}{cells}")
    model = ctrls[-1].model
    crit = min(p.force_crit_n for p in model.populations)
    print(f"\n5. the CAPR read-out behind it: the disc is pressed past its height at F_crit = {crit:.3f} N and every "
          "unit of the fingertip gets an input; activated-mean rate (Hz) / activated units at the end of the hold, "
          "and peak")
    for level in (1.0, 1.5, 2.0, 2.1, 2.2, 2.3, 2.5, 2.75, 3.0):
        model.reset()
        r = model.run(np.minimum(np.arange(int((level / 8.0 + 1.0) * RATE_HZ) + 1) / RATE_HZ * 8.0, level))
        cells = "  ".join(f"{t} {r.rates[t][-1]:5.1f}/{int(r.active[t][-1]):3d} (peak {r.rates[t].max():5.1f})"
                          for t in r.rates)
        print(f"{level:7.2f}  {cells}")


if __name__ == "__main__":
    from script_usage import argv_or_usage

    argv_or_usage(__doc__)
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 40, float(sys.argv[2]) if len(sys.argv) > 2 else 5.3)
