"""Parameters of the needle–tissue model of seed 001: every value, its unit, and what keeps the 1 kHz loop stable.

The model takes plain numbers by name (:meth:`NeedleParams.from_mapping`); the protocol's per-layer blocks and
the Table 1 values per scenario live in ``protocols/needle_insertion.yaml`` and
:mod:`studyctl.controllers.needle`. The force law that uses them is :mod:`studyctl.models.needle`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields
from typing import Any

from studyctl.errors import ModelParameterError

# Units of every parameter, for messages and documentation.
UNITS: dict[str, str] = {
    "capsule_k_stiff": "N/m",
    "capsule_puncture_n": "N",
    "liver_k_cut": "N·s/m",
    "liver_f_dynamic": "N",
    "liver_f_static": "N",
    "liver_c": "N·s/m²",
    "tumour_k_stiff": "N/m",
    "tumour_puncture_n": "N",
    "tumour_k_cut": "N·s/m",
    "tumour_f_dynamic": "N",
    "tumour_f_static": "N",
    "tumour_c": "N·s/m²",
    "radial_kp": "N/m",
    "radial_kd": "N·s/m",
    "tolerance_mm": "mm",
    "damping_band_mm": "mm",
    "radial_max_n": "N",
    "friction_ref_length_mm": "mm",
    "stick_band_mm_s": "mm/s",
    "stick_k": "N/m",
    "stick_d": "N·s/m",
    "contact_d": "N·s/m",
    "maintain_blend_s": "s",
    "track_match_mm": "mm",
    "track_match_deg": "deg",
    "radial_entry_line": "0/1",
    "rate_hz": "Hz",
}


@dataclass(frozen=True)
class NeedleParams:
    """Every parameter of the needle–tissue model and the guidance, with its default (Table 1, BL).

    Axial (Table 1): ``capsule_k_stiff``; ``liver_k_cut``, ``liver_f_dynamic``, ``liver_f_static``,
    ``liver_c``; ``tumour_k_stiff``, ``tumour_k_cut``, ``tumour_f_dynamic``, ``tumour_f_static``,
    ``tumour_c``. Radial (Table 1): ``radial_kp``, ``radial_kd`` (also the maintain-mode gains, eq. 8).

    Not in the paper (our choices, see the module docstring): ``capsule_puncture_n``,
    ``tumour_puncture_n``, ``tolerance_mm`` (tolerance capsule radius t), ``damping_band_mm`` (radial
    damper fade-in beyond t), ``radial_max_n`` (the guidance spring saturates here, so a needle held far
    from the path — before the approach — is pulled, not thrown), ``friction_ref_length_mm`` (embedded
    length at which friction reaches the Table 1 level), ``stick_band_mm_s`` (Karnopp band ε),
    ``stick_k``/``stick_d`` (stick anchor),
    ``contact_d`` (damping while a surface is pushed: the K·T/2 rule), ``maintain_blend_s``,
    ``track_match_mm``/``track_match_deg`` (a re-insertion this close to an earlier track reuses it),
    ``radial_entry_line`` (0/1, which line the radial guidance pulls towards once the needle is in tissue, below),
    ``rate_hz`` (servo rate; the K·T/2 damping rule depends on it).

    ``radial_entry_line``: 0 (the default, as every shipped protocol has run) pulls the needle towards the planned
    line, from the planned incision point to the tumour centroid, in tissue as outside it. 1 is eq. (1) as the paper
    words it (§2.3.1): ``d`` is "the orthogonal vector from the incision point to the virtual needle", and "the
    incision point is the location where the needle penetrates the tissue", while "once the needle penetrates the
    virtual tissue fixture, the needle angle is maintained". In tissue the guidance then holds the needle on the
    line it entered along (through its entry point, along its frozen axis), so it damps tremor but resists a
    correction of a misaligned entry beyond the tolerance ("compliant force feedback gave more freedom to the user
    to correct for misalignment"); outside the tissue, where there is no entry point yet, it pulls towards the
    planned line as before.
    """

    capsule_k_stiff: float = 100.0
    capsule_puncture_n: float = 1.0
    liver_k_cut: float = 5.0
    liver_f_dynamic: float = 0.8
    liver_f_static: float = 1.0
    liver_c: float = 10.0
    tumour_k_stiff: float = 0.0
    tumour_puncture_n: float = 1.5
    tumour_k_cut: float = 7.0
    tumour_f_dynamic: float = 0.9
    tumour_f_static: float = 1.1
    tumour_c: float = 10.5
    radial_kp: float = 100.0
    radial_kd: float = 30.0
    tolerance_mm: float = 1.0
    damping_band_mm: float = 0.5
    radial_max_n: float = 2.0
    friction_ref_length_mm: float = 150.0
    stick_band_mm_s: float = 2.0
    stick_k: float = 1000.0
    stick_d: float = 2.0
    contact_d: float = 1.0
    maintain_blend_s: float = 0.1
    track_match_mm: float = 1.0
    track_match_deg: float = 3.0
    radial_entry_line: float = 0.0
    rate_hz: float = 1000.0

    @classmethod
    def names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))

    @classmethod
    def from_mapping(cls, params: Mapping[str, Any], *, where: str = "needle parameters") -> NeedleParams:
        """Build from plain numbers by parameter name (the defaults fill the rest), then :meth:`validate`.

        The protocol's per-layer blocks (``liver: {k_cut: 5}``) and the Table 1 values themselves live in the
        protocol file; :mod:`studyctl.controllers.needle` turns its blocks into these names. Unknown names,
        non-numbers and unstable values raise :class:`~studyctl.errors.ModelParameterError` naming the field,
        the value and what is allowed.
        """
        allowed = cls.names()
        values: dict[str, float] = {}
        for name, value in params.items():
            if name not in allowed:
                raise ModelParameterError(f"{where}: unknown parameter {name!r}; allowed: {', '.join(allowed)}")
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ModelParameterError(f"{where}: {name} = {value!r} is not a number; give a value in {UNITS[name]}")
            values[name] = float(value)
        out = cls(**values)
        out.validate(where=where)
        return out

    def to_dict(self) -> dict[str, float]:
        return asdict(self)

    def validate(self, *, where: str = "needle parameters") -> None:
        """Refuse values that make the model meaningless, or springs under-damped for the servo rate (``K·T/2``)."""
        for f in fields(self):
            v = getattr(self, f.name)
            if not math.isfinite(v):
                raise ModelParameterError(f"{where}: {f.name} = {v} is not finite; give a number in {UNITS[f.name]}")
        nonneg = (
            "capsule_k_stiff", "tumour_k_stiff", "radial_kp", "stick_k",
            "liver_k_cut", "tumour_k_cut", "liver_f_dynamic", "liver_f_static", "tumour_f_dynamic",
            "tumour_f_static", "liver_c", "tumour_c", "radial_kd", "stick_d", "contact_d", "tolerance_mm",
        )  # fmt: skip
        for name in nonneg:
            v = getattr(self, name)
            if v < 0:
                kind = "stiffness" if ("k_stiff" in name or name in ("radial_kp", "stick_k")) else "value"
                raise ModelParameterError(
                    f"{where}: {name} = {v:g} {UNITS[name]} is a negative {kind}; it must be ≥ 0 "
                    "(a negative spring or damper adds energy and makes the loop unstable)"
                )
        positive = (
            "capsule_puncture_n", "tumour_puncture_n", "friction_ref_length_mm", "stick_band_mm_s",
            "damping_band_mm", "rate_hz", "track_match_mm", "track_match_deg", "radial_max_n",
        )  # fmt: skip
        for name in positive:
            v = getattr(self, name)
            if v <= 0:
                raise ModelParameterError(f"{where}: {name} = {v:g} {UNITS[name]} must be > 0")
        if self.radial_entry_line not in (0.0, 1.0):
            raise ModelParameterError(
                f"{where}: radial_entry_line = {self.radial_entry_line:g} must be 0 (guidance towards the planned "
                "line) or 1 (towards the line the needle entered the tissue along)"
            )
        if self.maintain_blend_s < 1.0 / self.rate_hz:
            raise ModelParameterError(
                f"{where}: maintain_blend_s = {self.maintain_blend_s:g} s is shorter than one tick "
                f"({1.0 / self.rate_hz:g} s at {self.rate_hz:g} Hz); the mode switch would jump — use ≥ 0.05 s"
            )
        for layer in ("liver", "tumour"):
            fd, fs = getattr(self, f"{layer}_f_dynamic"), getattr(self, f"{layer}_f_static")
            if fd > fs:
                raise ModelParameterError(
                    f"{where}: {layer}_f_dynamic = {fd:g} N exceeds {layer}_f_static = {fs:g} N; Karnopp "
                    "friction needs dynamic ≤ static"
                )
        # Sampled-spring damping rule at the servo rate (not a passivity guarantee; see min_damping_for_rate).
        for spring, damper, stiffness in self.spring_damper_pairs():
            bound = min_damping_for_rate(stiffness, self.rate_hz)
            d = getattr(self, damper)
            if d < bound:
                raise ModelParameterError(
                    f"{where}: {damper} = {d:g} N·s/m is below the sampled-spring damping rule K·T/2 = "
                    f"{bound:.4g} N·s/m "
                    f"(K = {spring} = {stiffness:.4g} N/m at {self.rate_hz:g} Hz); set {damper} ≥ {bound:.4g} "
                    f"or lower {spring.split(' ')[0]}"
                )

    def spring_damper_pairs(self) -> list[tuple[str, str, float]]:
        """(spring name, damper name, largest local stiffness N/m) for every virtual spring."""
        return [
            ("radial_kp", "radial_kd", self.radial_kp),
            ("stick_k", "stick_d", self.stick_k),
            (
                "capsule_k_stiff (local, at puncture)",
                "contact_d",
                local_stiffness_at_puncture(self.capsule_k_stiff, self.capsule_puncture_n),
            ),
            (
                "tumour_k_stiff (local, at puncture)",
                "contact_d",
                local_stiffness_at_puncture(self.tumour_k_stiff, self.tumour_puncture_n),
            ),
        ]


def min_damping_for_rate(stiffness_n_per_m: float, rate_hz: float) -> float:
    """Smallest virtual damping (N·s/m) the model accepts beside a spring of stiffness K at rate 1/T: ``K·T/2``.

    What this is and is not. Colgate & Schenkel (1997) show that a zero-order-hold virtual wall (spring K,
    virtual damper B) sampled every T is passive only if the device's *physical* damping b exceeds
    ``K·T/2 + |B|``: a virtual damper does not buy passivity (it raises the physical damping needed), so this
    model guarantees no passivity of a real device (the Omega.6's physical damping is not in the paper). The
    rule here is a design heuristic on the same K·T/2 scale: each virtual spring is rendered with at least that
    much virtual damping. In the simulated loop (hand and handle integrated by the simulated device, the model
    at the servo rate) it keeps the closed-loop energy from growing, and without the damper the energy grows
    (``tests/needle/test_model_physics.py::test_closed_loop_energy_does_not_grow``). Rates at which a Table 1
    damper falls below it are refused because the simulation has not been shown well-behaved there.
    """
    return stiffness_n_per_m / (2.0 * rate_hz)


def local_stiffness_at_puncture(k: float, puncture_n: float) -> float:
    """dF/dΔx of ``k·Δx² + k·Δx`` at the puncture displacement (N/m); the largest along the spring."""
    if k <= 0.0:
        return 0.0
    return k * math.sqrt(1.0 + 4.0 * puncture_n / k)
