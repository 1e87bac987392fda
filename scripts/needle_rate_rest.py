"""Where a scripted hand brings the seed-001 needle to rest at 1 kHz and at a reduced simulation loop rate.

Usage: ``python scripts/needle_rate_rest.py [RATE] [comp]`` (default 250 Hz; ``comp`` adds each virtual spring's
K·ΔT/2 to its damper at the reduced rate, ΔT = 1/RATE − 1/1000: what a damper would need to keep the K·T/2 rule's
margin of 1 kHz).

No virtual operator: the simulated device's hand (0.5 kg, 300 N/m, 8 N·s/m to its reference, the device's
defaults) follows a reference that advances along the vertical needle axis at 3, 8 or 15 mm/s to a stop depth
(30 mm in liver; 52-54.5 mm short of the tumour; 56 mm: onto the tumour, 1.25 mm radius centred at 55 mm), then
holds for 3 s. The needle model runs at the loop rate (its force held between loop ticks; the device integrates at
1 kHz), with the shipped protocol's BL, ES and EG parameters. Printed per case: the tip's rest depth at each rate,
their difference, the tip's RMS velocity over the last second (ringing) and the end state (layer, punctures,
stuck). Why: at 250 Hz the ES/ESG tumour contact damper (1 N·s/m) is below the K·T/2 rule (2.0 N·s/m) and the
stick anchor's (2 N·s/m) is at it; this shows whether that moves where the needle stops (it does not: issue 22,
docs/performance.md, loop rate).
"""

from __future__ import annotations

import numpy as np

from studyctl.controllers.needle import flat_params
from studyctl.devices.force3d import SimulatedForceDevice
from studyctl.models.needle import NeedleParams, NeedleTissueModel
from studyctl.models.needle_guidance import NeedleGeometry
from studyctl.protocol import load_protocol, resolve_protocol

GEOMETRY = NeedleGeometry((0.0, 0.0, -25.0), 55.0, (0.0, 0.0, -25.0), 1.25, (0.0, 0.0, 30.0))
START_Z, SURFACE_Z = 35.0, 30.0


def scenario_params(protocol, condition: str) -> NeedleParams:  # noqa: ANN001
    return NeedleParams.from_mapping(flat_params(dict(protocol.condition(condition).params)))


def compensate(model: NeedleTissueModel, p: NeedleParams, rate: float) -> None:
    """Each damper plus its spring's K·ΔT/2 (the contact damper takes the stiffer of capsule and tumour)."""
    dt = 1.0 / rate - 1.0 / p.rate_hz
    contact_k = max(k for _, damper, k in p.spring_damper_pairs() if damper == "contact_d")
    model._stick_d_mm = (p.stick_d + p.stick_k * dt / 2) * 1e-3
    model._contact_d_mm = (p.contact_d + contact_k * dt / 2) * 1e-3
    model._kd_mm = (p.radial_kd + p.radial_kp * dt / 2) * 1e-3


def rest(p: NeedleParams, rate: float, stop_mm: float, speed: float, comp: bool) -> tuple[float, float, str]:
    model = NeedleTissueModel(p, GEOMETRY)
    model.set_loop_rate(rate)
    if comp and rate < p.rate_hz:
        compensate(model, p, rate)
    dev = SimulatedForceDevice({"device_class": "omega6"})
    dev.open()
    dev.apply_input({"x_mm": 0.0, "y_mm": 0.0, "z_mm": START_Z, "dir_x": 0.0, "dir_y": 0.0, "dir_z": -1.0,
                     "button": 1.0})
    t_move = (stop_mm + START_Z - SURFACE_Z) / speed
    n = int((t_move + 3.0) * rate)
    vz = np.empty(n + 1)
    z = 0.0
    for k in range(n + 1):
        t = k / rate
        dev.apply_input({"x_mm": 0.0, "y_mm": 0.0, "z_mm": START_Z - speed * min(t, t_move)})
        o = dev.read(t).values
        f = model.step(o["x_mm"], o["y_mm"], o["z_mm"], o["vx_mm_s"], o["vy_mm_s"], o["vz_mm_s"], 0.0, 0.0, -1.0)
        dev.write({"fx_n": f[0], "fy_n": f[1], "fz_n": f[2]})
        pos, vel = dev.true_state
        z, vz[k] = pos[2], vel[2]
    ringing = float(np.sqrt(np.mean(vz[-int(rate):] ** 2)))
    return SURFACE_Z - z, ringing, f"{model.layer}/{model.punctures}/{model.stuck}"


def main(argv: list[str]) -> None:
    rate = float(argv[0]) if argv and argv[0] != "comp" else 250.0
    comp = "comp" in argv
    protocol = load_protocol(resolve_protocol("needle_insertion"))
    print(f"rest depth (mm) at 1000 Hz and {rate:g} Hz{' (dampers + K·ΔT/2)' if comp else ''}; ringing = RMS tip "
          "velocity (mm/s) over the last second; end state layer/punctures/stuck")
    diffs = []
    for scenario in ("BL", "ES", "EG"):
        p = scenario_params(protocol, scenario)
        for stop in (30.0, 52.0, 53.5, 54.5, 56.0):
            for speed in (3.0, 8.0, 15.0):
                a, b = rest(p, 1000.0, stop, speed, comp), rest(p, rate, stop, speed, comp)
                diffs.append(b[0] - a[0])
                print(f"{scenario:3s} stop {stop:4.1f} mm at {speed:2.0f} mm/s: {a[0]:7.3f} vs {b[0]:7.3f} "
                      f"({b[0] - a[0]:+.4f}); ringing {a[1]:.3f} vs {b[1]:.3f}; {a[2]} vs {b[2]}")
    d = np.array(diffs)
    print(f"rest depth at {rate:g} Hz minus 1 kHz: mean {d.mean():+.4f} mm, mean |d| {np.abs(d).mean():.4f}, "
          f"max |d| {np.abs(d).max():.4f} ({len(d)} cases)")


if __name__ == "__main__":
    from script_usage import argv_or_usage

    main(argv_or_usage(__doc__))
