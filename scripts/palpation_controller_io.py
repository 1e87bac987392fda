"""Seed 000's controllers against sensor force: the paper's Fig. 4 experiment, and its Fig. 3b check.

Usage: ``python scripts/palpation_controller_io.py`` (about 10-20 s CPU). Noiseless force trapezoids go straight
into the shipped linear, piecewise and bio-inspired controllers at the sensor's 50 Hz; no scene, no person.

1. **The paper's Fig. 4 waves.** The BHF code makes them in ``[Fig. 5 and 8]_Control_curves.py``: (a) 0.8 N at
   0.5 and at 2 N/s, (b) 0.4 and 0.8 N at 2 N/s (holds of several seconds; here 3 s). Per controller: the balloon
   and vibration commands at the ramp's top, at the end of the hold and 0.3 s after the force is back at 0, and
   the vibration's largest after the release, with the bio-inspired controller's SA1 / RA1 activated-mean rates at
   the same instants. The paper's text on them: the balloon "changes in almost same way as SA1 afferent
   responses" (onset and hold, not offset), the vibration like RA1 and PC (onset and offset, not the hold).
2. **Command against force, 0-4 N.** Trapezoids to each peak at 0.5, 2, 8 and 16 N/s (a v5 press: 5.3 mm at
   18.9 mm/s, 0.28 s, to 2.2 N on sponge, about 8 N/s on average) with a 1.5 s hold: the bio-inspired balloon's
   largest command while rising / held, its vibration's, SA1's held rate, and the linear and piecewise held
   commands. Then the lowest peak whose rise puts the bio-inspired balloon at the 99 cap, per rate, and the held
   curve's.
3. **Does the balloon follow SA1?** Over each wave of 2: the correlation of ln(C_p/C0) with the SA1 rate (eq. 3
   and eq. 6 make them proportional below the cap) and the share of ticks at the cap while SA1 still rose.
4. **Fig. 3b, the balloon's own stimuli** (``models.bhf_constants``): the forces the balloon puts on a 2 mm disc,
   SA1's rate for each, how linear the rate is in the force (R², the paper: "below the force level that causes SA1
   afferent responses to saturate") and the model intensity against the magnitudes (the paper's R² = 0.98), for
   the stimuli over the balloon's whole range (the shipped constants) and for those below SA1 saturation
   (``top="unsaturated"``; the controller's K_PF_UNSATURATED / W_BALLOON_UNSATURATED, whose held balloon command is
   the last column of 2).
"""

from __future__ import annotations

import math

import numpy as np

from studyctl.controllers.bio_inspired import K_PF_UNSATURATED, W_BALLOON_UNSATURATED, BioInspiredController
from studyctl.controllers.palpation import LinearController, PiecewiseController
from studyctl.models.bhf_constants import balloon_constants
from studyctl.plugins.interfaces import Observation

RATE_HZ = 50.0
CAP = 99.0


def trapezoid(peak: float, rate: float, hold: float, tail: float = 1.0) -> np.ndarray:
    """Force per 50 Hz tick: 0.2 s at rest, up at ``rate`` N/s, held ``hold`` s, down, ``tail`` s at rest."""
    ramp = peak / rate
    t = np.arange(int((0.2 + 2 * ramp + hold + tail) * RATE_HZ) + 1) / RATE_HZ - 0.2
    up = np.clip(t / ramp, 0.0, 1.0)
    down = np.clip((t - ramp - hold) / ramp, 0.0, 1.0)
    return peak * np.where(t < ramp + hold, up, 1.0 - down)


def drive(ctrl, force: np.ndarray) -> np.ndarray:
    """Columns balloon %, vibration %, SA1 Hz, RA1 Hz per tick (rates 0 for controllers without CAPR)."""
    ctrl.reset()
    rows = []
    for k, f in enumerate(force):
        cmd = ctrl.step(Observation(k / RATE_HZ, {"force_n": float(f)}))
        rates = getattr(ctrl, "last_rates", {})
        rows.append((cmd["balloon_pct"], cmd["vibration_pct"], rates.get("SA1", 0.0), rates.get("RA1", 0.0)))
    return np.array(rows)


def phases(force: np.ndarray) -> tuple[int, int, int]:
    """Tick of the ramp's top, the hold's last tick, first tick of the release."""
    top = int(np.argmax(force))
    last = int(np.flatnonzero(force == force.max())[-1])
    return top, last, last + 1


def fig4(ctrls) -> None:
    print("1. The paper's Fig. 4 waves (BHF code [Fig. 5 and 8]_Control_curves.py), 3 s hold: balloon | vibration %"
          " at the ramp's top / end of hold / 0.3 s after the force is back at 0; bio-inspired also SA1 | RA1 Hz")
    waves = (("(a) 0.8 N at 0.5 N/s", 0.8, 0.5), ("(a) 0.8 N at 2 N/s", 0.8, 2.0), ("(b) 0.4 N at 2 N/s", 0.4, 2.0))
    for label, peak, rate in waves:
        force = trapezoid(peak, rate, 3.0)
        top, last, rel = phases(force)
        print(f"  {label}")
        for ctrl in ctrls:
            tr = drive(ctrl, force)
            after = rel + int(0.3 * RATE_HZ) + int(peak / rate * RATE_HZ)  # 0.3 s after the force is back at 0
            cells = [f"{tr[i, 0]:5.1f} | {tr[i, 1]:5.1f}" for i in (top, last, after)]
            line = f"    {ctrl.name:13s} " + "   ".join(cells) + f"   vib. max after release {tr[rel:, 1].max():5.1f}"
            if ctrl.name == "bio_inspired":
                hz = [f"{tr[i, 2]:5.1f} | {tr[i, 3]:5.1f}" for i in (top, last, after)]
                line += (f"\n    {'SA1 | RA1 Hz':13s} " + "   ".join(hz)
                         + f"   RA1 max after release {tr[rel:, 3].max():5.1f}")
            print(line)


def sweep(ctrls, peaks, rates) -> dict[tuple[float, float], np.ndarray]:
    bio, lin, pw, unsat = ctrls
    traces = {}
    print("\n2. Command against force: peak N, then per rise rate the bio-inspired balloon's largest while rising / "
          "held (end of 1.5 s hold), vibration's the same, SA1 held Hz; linear and piecewise held balloon|vibration")
    print(f"{'peak':>5s} {'N/s':>5s} {'bio balloon':>12s} {'bio vibration':>14s} {'SA1 held':>9s} "
          f"{'RA1 rise':>9s} {'linear held':>12s} {'piecewise held':>15s} {'unsat. held':>11s}")
    for peak in peaks:
        for rate in rates:
            force = trapezoid(peak, rate, 1.5)
            top, last, _ = phases(force)
            tb = drive(bio, force)
            traces[(peak, rate)] = np.column_stack([force, tb])
            tl, tp, tu = drive(lin, force)[last], drive(pw, force)[last], drive(unsat, force)[last]
            print(f"{peak:5.2f} {rate:5.1f} {tb[:top + 1, 0].max():5.1f} /{tb[last, 0]:5.1f} "
                  f"{tb[:top + 1, 1].max():6.1f} /{tb[last, 1]:5.1f} {tb[last, 2]:9.1f} {tb[:top + 1, 3].max():9.1f} "
                  f"{tl[0]:5.1f} |{tl[1]:5.1f} {tp[0]:7.1f} |{tp[1]:5.1f} {tu[0]:11.1f}")
    return traces


def cap_forces(traces, peaks, rates) -> None:
    print("\n   lowest peak whose rise puts the bio-inspired balloon at the cap (99), and whose hold keeps it there:")
    for rate in rates:
        rise = [p for p in peaks if traces[(p, rate)][:, 1].max() >= CAP]
        held = [p for p in peaks if phases(traces[(p, rate)][:, 0]) and
                traces[(p, rate)][phases(traces[(p, rate)][:, 0])[1], 1] >= CAP]
        print(f"   {rate:5.1f} N/s: rising {min(rise) if rise else '-'} N, held {min(held) if held else '-'} N "
              f"(held at the cap: {', '.join(f'{p:g}' for p in held) or 'none'})")


def follows_sa1(traces, c0: float) -> None:
    print("\n3. Does the bio-inspired balloon follow SA1? per wave of 2: r(ln(C/C0), SA1) over ticks below the cap; "
          "share of ticks at the cap while SA1 rose")
    for (peak, rate), tr in traces.items():
        if peak not in (0.4, 0.8, 1.2, 2.0, 3.0, 4.0) or rate not in (0.5, 16.0):
            continue
        c, sa1 = tr[:, 1], tr[:, 3]
        below = (c < CAP) & (c > c0)
        r = float(np.corrcoef(np.log(c[below] / c0), sa1[below])[0, 1]) if below.sum() > 3 else math.nan
        rising = np.diff(sa1, prepend=sa1[0]) > 0.05
        capped = float(np.mean(c[rising] >= CAP)) if rising.any() else 0.0
        print(f"   {peak:4.1f} N at {rate:4.1f} N/s: r {r:5.3f} over {int(below.sum()):3d} ticks; "
              f"at the cap in {100 * capped:5.1f} % of {int(rising.sum())} ticks where SA1 rose")


def fig3b(top: str) -> None:
    k = balloon_constants(top=top)
    force = k.to_frame()
    from studyctl.models.palpation_hw import K_PSI_N_PER_MM2, BalloonModel  # only here: the balloon's own force
    psi = np.array([BalloonModel().static_psi(c) for c in k.control])
    newton = psi * K_PSI_N_PER_MM2 * math.pi * 2.0**2 / 2.0
    fit = np.polyfit(newton, k.model_rate_hz, 1)
    r2_rate = 1 - np.sum((np.polyval(fit, newton) - k.model_rate_hz) ** 2) / np.sum(
        (k.model_rate_hz - k.model_rate_hz.mean()) ** 2)
    mi = force["model_intensity"].to_numpy()
    r2_mag = float(np.corrcoef(mi, k.magnitude)[0, 1] ** 2)
    print(f"\n4. Fig. 3b, stimuli top={top!r}: the balloon's own stimuli (2 mm disc, psi·K_psi·π·r²/2), the paper's "
          "procedure on our CAPR")
    print(f"   control {k.control[0]:.0f}-{k.control[-1]:.0f}: force {newton[0]:.3f}-{newton[-1]:.3f} N, SA1 "
          f"{k.model_rate_hz[0]:.1f}-{k.model_rate_hz[-1]:.1f} Hz; R² of SA1 linear in force {r2_rate:.4f}; "
          f"K_pf {k.k:.4f}, C0 {k.c0:.0f}, w {k.w:.5f}; R² model intensity vs magnitude {r2_mag:.4f} (paper 0.98)")
    print("   SA1 Hz per stimulus: " + ", ".join(f"{n:.3f} N {r:.1f}" for n, r in zip(newton, k.model_rate_hz,
                                                                                          strict=True)))


def main() -> None:
    unsat = BioInspiredController({"k_pf": K_PF_UNSATURATED, "w_balloon": W_BALLOON_UNSATURATED, "drive": ["balloon"]})
    ctrls = (BioInspiredController({}), LinearController({}), PiecewiseController({}), unsat)
    fig4((ctrls[1], ctrls[2], ctrls[0]))
    peaks = (0.2, 0.4, 0.6, 0.8, 1.0, 1.2, 1.6, 2.0, 2.5, 3.0, 4.0)
    rates = (0.5, 2.0, 8.0, 16.0)
    traces = sweep(ctrls, peaks, rates)
    cap_forces(traces, peaks, rates)
    follows_sa1(traces, ctrls[0].params["c0_balloon"])
    fig3b("range")
    fig3b("unsaturated")


if __name__ == "__main__":
    from script_usage import argv_or_usage

    argv_or_usage(__doc__)
    main()
