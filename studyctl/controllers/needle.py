"""The 1 kHz hybrid controller of seed 001: axial needle–tissue forces and radial guidance.

See :mod:`studyctl.models.needle` for the force law; this module adapts it to the plugin interfaces.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from studyctl.errors import ModelParameterError
from studyctl.models.needle import NeedleTissueModel
from studyctl.models.needle_guidance import NeedleGeometry
from studyctl.models.needle_params import UNITS, NeedleParams
from studyctl.plugins.interfaces import Controller, Observation, Scene
from studyctl.plugins.params import ParamProblem, unknown_param


class NeedleHybridController(Controller):
    """Hybrid position/force controller of Selim et al. (2024) at 1 kHz.

    Parameters (protocol ``params``; SI units as in the paper's Table 1, whose values per scenario are written
    once, in the conditions of ``protocols/needle_insertion.yaml``)
    --------------------------------------------------------------------------------------------------------
    capsule_k_stiff : float
        Capsule stiffness k_stiff (N/m), eq. (3). Table 1: 100.
    liver_k_cut, liver_f_dynamic, liver_f_static, liver_c : float
        Liver tissue cutting coefficient (N·s/m), dynamic and static friction (N), depth damping c. Table 1:
        5, 0.8, 1, 10.
    tumour_k_stiff, tumour_k_cut, tumour_f_dynamic, tumour_f_static, tumour_c : float
        Tumour: BL/RT/EG 0, 7, 0.9, 1.1, 10.5; ES/ESG 1000, 10, 1.4, 1.8, 15. (``tumor_*`` also accepted.)
    radial_kp, radial_kd : float
        Radial guidance and maintain-mode gains (N/m, N·s/m), eqs. (1) and (8). Table 1: BL/RT/ES 100/30,
        EG 1000/70, ESG 1000/50.
    radial_entry_line : float
        0 (default): the radial guidance pulls towards the planned line (incision point → tumour centroid). 1: in
        tissue, towards the line the needle entered along (eq. 1 as §2.3.1 words it; see NeedleParams).
    tolerance_mm, radial_max_n, capsule_puncture_n, tumour_puncture_n, friction_ref_length_mm, …
        Choices the paper does not state (defaults 1 mm, 2 N, 1 N, 1.5 N, 150 mm); see
        :class:`studyctl.models.needle.NeedleParams` for all of them and why.

    Per-layer blocks are accepted too, as the shipped protocol writes them: ``capsule: {k_stiff}``,
    ``liver: {k_cut, f_dynamic, f_static, c}``, ``tumour: {…}`` and ``radial: {k_p, k_d}``.

    Observation channels: ``x_mm``, ``y_mm``, ``z_mm`` (needle tip), ``vx_mm_s``… (estimated here by a
    20 ms finite difference when the device does not report them), ``dir_x``/``dir_y``/``dir_z`` (pen
    axis, default straight down), ``button`` (1 = inserting, 0 = maintain; default 1). A device fault
(``Observation.faults`` or a non-zero ``fault`` channel) or a non-finite position gives zero force.

    Command channels: ``fx_n``, ``fy_n``, ``fz_n`` (device frame). The model state of each tick is in
    :attr:`diagnostics` (updated in place; the trial loop logs it with every sample): ``f_axial_n``,
    ``f_radial_n``, ``depth_mm``, ``layer`` (0 outside, 1 capsule, 2 liver, 3 tumour surface, 4 tumour),
    ``stuck``, ``maintain`` (0…1 blend), ``punctures`` and ``needle_dir_x``/``_y``/``_z`` (the needle axis,
    frozen while in tissue — what the CT view draws). Model events (``capsule_contact``,
    ``capsule_puncture``, ``tumour_contact``, ``tumour_puncture``, ``track_reused``, ``needle_withdrawn``)
    collect in :attr:`events` as ``{"kind": …, "depth_mm": …}``.
    """

    name = "needle_hybrid"
    rate_hz = 1000.0
    # The force law takes the measured tip velocity and holds no per-step state but the maintain cross-fade and
    # the fallback velocity window, both rescaled by set_loop_rate, so a simulated session may run it below
    # 1 kHz (the simulated device still integrates at its own rate; `studyctl bench simrate` measures it).
    rate_adjustable = True

    def __init__(self, params: Mapping[str, Any], scene: Scene | None = None) -> None:
        super().__init__(params, scene)
        where = "controller needle_hybrid params"
        self.model_params = NeedleParams.from_mapping(flat_params(params, where=where), where=where)
        self.rate_hz = self.model_params.rate_hz
        geometry_of = getattr(scene, "geometry", None)
        if geometry_of is None:
            raise ModelParameterError(
                "controller needle_hybrid needs a scene with the needle geometry (scene needle_liver); "
                f"got {type(scene).__name__ if scene is not None else 'no scene'}"
            )
        geometry = geometry_of()
        if not isinstance(geometry, NeedleGeometry):
            raise ModelParameterError(
                f"controller needle_hybrid: scene {type(scene).__name__}.geometry() must return a NeedleGeometry"
            )
        self.model = NeedleTissueModel(self.model_params, geometry)
        self.events: list[dict[str, Any]] = []
        self.diagnostics: dict[str, float] = {}
        self.set_loop_rate(self.rate_hz)  # the velocity window and cross-fade at the device's own rate
        self.reset()

    @classmethod
    def needs(cls, params: Mapping[str, Any]) -> frozenset[str]:
        """The scene's layer geometry; the view is the visual channel's business, not the controller's."""
        return frozenset({"layers"})

    @classmethod
    def param_problems(cls, params: Mapping[str, Any]) -> list[ParamProblem]:
        """Every refused parameter, at its key (``liver.k_cut``), for ``studyctl protocol check``."""
        flat, paths, problems = _flatten(params)
        names = NeedleParams.names()
        for name, value in flat.items():
            if name not in names:
                if len(paths[name]) == 2:  # liver.k_cutt: name and suggest the keys of that block (k_cut, …)
                    prefix = name[: len(name) - len(paths[name][1])]
                    problems.append(unknown_param(paths[name], [n.removeprefix(prefix) for n in names
                                                                if n.startswith(prefix)]))
                else:
                    problems.append(unknown_param(paths[name], names))
            elif isinstance(value, bool) or not isinstance(value, int | float):
                problems.append(ParamProblem(paths[name], "not a number", f"a number in {UNITS[name]}"))
        if problems:
            return problems
        try:
            NeedleParams.from_mapping(flat, where="needle model")
        except ModelParameterError as exc:
            # validate() names the field first ("needle model: radial_kd = 0.1 N·s/m is below …"): point at it
            text = str(exc).removeprefix("needle model: ")
            field = text.split(" ", 1)[0]
            return [ParamProblem(paths.get(field, ()), "refused by the needle model", text)]
        return []

    def set_loop_rate(self, rate_hz: float) -> None:
        self.model.set_loop_rate(rate_hz)
        self._window = max(1, round(0.02 * rate_hz))  # the 20 ms finite difference, in this loop's steps

    def reset(self) -> None:
        self.model.reset()
        self.events.clear()
        self._hist: list[tuple[float, float, float, float]] = []
        self.diagnostics.update(
            f_axial_n=0.0,
            f_radial_n=0.0,
            depth_mm=0.0,
            layer=0.0,
            stuck=0.0,
            maintain=0.0,
            punctures=0.0,
            needle_dir_x=0.0,
            needle_dir_y=0.0,
            needle_dir_z=-1.0,
        )

    def _velocity(self, t: float, x: float, y: float, z: float) -> tuple[float, float, float]:
        """Finite difference over the last 20 ms for devices that report no velocity."""
        hist = self._hist
        hist.append((t, x, y, z))
        if len(hist) > self._window + 1:
            del hist[0]
        t0, x0, y0, z0 = hist[0]
        dt = t - t0
        if dt <= 0.0:
            return 0.0, 0.0, 0.0
        return (x - x0) / dt, (y - y0) / dt, (z - z0) / dt

    def step(self, obs: Observation) -> dict[str, float]:
        v = obs.values
        px, py, pz = v["x_mm"], v["y_mm"], v["z_mm"]
        if obs.faults or v.get("fault", 0.0) or not (math.isfinite(px) and math.isfinite(py) and math.isfinite(pz)):
            return {"fx_n": 0.0, "fy_n": 0.0, "fz_n": 0.0}
        if "vx_mm_s" in v:
            vx, vy, vz = v["vx_mm_s"], v["vy_mm_s"], v["vz_mm_s"]
        else:
            vx, vy, vz = self._velocity(obs.t, px, py, pz)
        if "dir_x" in v:
            ax, ay, az = v["dir_x"], v["dir_y"], v["dir_z"]
        else:
            ax, ay, az = 0.0, 0.0, -1.0
        m = self.model
        fx, fy, fz = m.step(px, py, pz, vx, vy, vz, ax, ay, az, v.get("button", 1.0) >= 0.5)
        if m.events:
            for kind, depth in m.events:
                self.events.append({"kind": kind, "depth_mm": depth})
            m.events.clear()
        u = m.axis
        d = self.diagnostics
        d["f_axial_n"] = m.f_axial
        d["f_radial_n"] = m.f_radial
        d["depth_mm"] = m.depth_mm
        d["layer"] = float(m.layer)
        d["stuck"] = float(m.stuck)
        d["maintain"] = m.maintain
        d["punctures"] = float(m.punctures)
        d["needle_dir_x"], d["needle_dir_y"], d["needle_dir_z"] = u
        return {"fx_n": fx, "fy_n": fy, "fz_n": fz}


# The protocol writes the parameters in per-layer blocks, as the paper's Table 1 groups them; the model takes
# flat names. ``tumor`` is accepted for ``tumour`` (block or prefix), ``k_p``/``k_d`` for ``kp``/``kd``.
_BLOCKS = ("capsule", "liver", "tumour", "tumor", "radial")
_KEY_ALIASES = {"k_p": "kp", "k_d": "kd"}
_RADIAL_PLAIN = ("tolerance_mm", "damping_band_mm")  # radial.max_n → radial_max_n


def flat_params(params: Mapping[str, Any], *, where: str = "needle_hybrid params") -> dict[str, Any]:
    """The model's flat parameter names from the protocol's layout (per-layer blocks, ``tumor``, ``k_p``)."""
    flat, _, problems = _flatten(params)
    if problems:
        first = problems[0]
        raise ModelParameterError(f"{where}: {'.'.join(first.key)}: {first.what}; allowed {first.allowed}")
    return flat


def _flatten(params: Mapping[str, Any]) -> tuple[dict[str, Any], dict[str, tuple[str, ...]], list[ParamProblem]]:
    """(flat model names → values, flat name → the key path it was written at, names given twice)."""
    flat: dict[str, Any] = {}
    paths: dict[str, tuple[str, ...]] = {}
    problems: list[ParamProblem] = []

    def put(name: str, value: Any, path: tuple[str, ...]) -> None:
        if name in flat:
            first = ".".join(paths[name])
            problems.append(ParamProblem(path, "given twice", f"one value for {name} (first at {first})"))
            return
        flat[name], paths[name] = value, path

    for key, value in params.items():
        key = str(key)
        if key in _BLOCKS and isinstance(value, Mapping):
            block = "tumour" if key == "tumor" else key
            for raw_sub, v in value.items():
                sub = _KEY_ALIASES.get(str(raw_sub), str(raw_sub))
                put(sub if (block == "radial" and sub in _RADIAL_PLAIN) else f"{block}_{sub}", v, (key, str(raw_sub)))
        else:
            put(key.replace("tumor_", "tumour_", 1) if key.startswith("tumor_") else key, value, (key,))
    return flat, paths, problems
