"""Perception for palpation feedback: the paper's eqs. 3-6 and a noisy Weber-law observer.

Eqs. 3-4 turn afferent firing rates into perceived intensities, eqs. 5-6 turn intensities (or a force)
back into actuator control amounts. :class:`Sense` is the observer a virtual participant feels the
actuators through: a detection threshold and log-normal noise whose size is set by a Weber fraction.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from studyctl.errors import ModelParameterError
from studyctl.models.palpation_hw import K_PSI_N_PER_MM2

# Eq. 4 weights of SA1, RA1, PC in perceived vibration intensity (paper: "set to 0.29, 0.36, 0.46").
VIBRATION_WEIGHTS = (0.29, 0.36, 0.46)


def perceived_force_intensity(rate_sa1_hz: float, k_pf: float) -> float:
    """Eq. 3: ``I_pf = K_pf · f̄_SA1 / 10``."""
    return k_pf * rate_sa1_hz / 10.0


def perceived_vibration_intensity(
    rate_sa1_hz: float,
    rate_ra1_hz: float,
    rate_pc_hz: float,
    k_pv: float,
    weights: tuple[float, float, float] = VIBRATION_WEIGHTS,
) -> float:
    """Eq. 4: ``I_pv = K_pv · (C_sa·f̄_SA1 + C_ra·f̄_RA1 + C_pc·f̄_PC) / 10``."""
    c_sa, c_ra, c_pc = weights
    return k_pv * (c_sa * rate_sa1_hz + c_ra * rate_ra1_hz + c_pc * rate_pc_hz) / 10.0


def inverse_perception(intensity: float, c0: float, weber: float, c_max: float = 99.0) -> float:
    """Eq. 6: the control amount that evokes a perceived intensity, ``C = C_0·(1 + w)^I``, capped at ``c_max``.

    ``C_0`` is the control amount at which the stimulus becomes discernible, ``w`` the Weber fraction
    (BHF code: ``psy_fucnt_*`` with the cap at 99).
    """
    if not (c0 > 0 and weber > 0 and c_max > 0):
        raise ModelParameterError(f"inverse perception: C0 = {c0}, w = {weber}, c_max = {c_max} must all be > 0")
    exponent = intensity * math.log1p(weber)
    if exponent > math.log(c_max / c0):
        return c_max
    return c0 * math.exp(exponent)


def balloon_control_for_force(
    force_n: float, r_p_mm: float = 2.0, k_psi: float = K_PSI_N_PER_MM2, c_p0: float = 36.0
) -> float:
    """Eq. 5: control amount of the balloon for a force on the skin, ``C_p = 5·F_p/(K_psi·π·r_p²) + C_p0``.

    Sources: K_psi = 6.896e-3 N/mm² per psi (paper); r_p = 2 mm and C_p0 = 36 (BHF code). Note that the
    BHF code's actuator fit (0.25 psi per unit above 36) and its skin-force model (``psi·K_psi·π·r_p²/2``)
    imply a factor 8, not 5; eq. 5 is implemented as printed.
    """
    if r_p_mm <= 0 or k_psi <= 0:
        raise ModelParameterError(f"eq. 5: r_p = {r_p_mm} mm and K_psi = {k_psi} must be > 0")
    return 5.0 * force_n / (k_psi * math.pi * r_p_mm**2) + c_p0


def balloon_force_for_control(control: float, r_p_mm: float = 2.0, k_psi: float = K_PSI_N_PER_MM2,
                              c_p0: float = 36.0) -> float:
    """Inverse of eq. 5 (N); 0 at or below ``c_p0``."""
    return max(control - c_p0, 0.0) * k_psi * math.pi * r_p_mm**2 / 5.0


@dataclass(frozen=True)
class Sense:
    """A noisy observer of one stimulus magnitude (balloon pressure, vibration acceleration).

    Each observation is ``magnitude·exp(σ·ε)``, ε ~ N(0, 1), with ``σ = ln(1 + weber)/(√2·0.6745)``: two
    stimuli one Weber fraction apart are told apart in 75 % of paired comparisons. Observations below
    ``threshold`` are not felt (0).
    """

    name: str
    threshold: float
    weber: float
    unit: str = ""

    def __post_init__(self) -> None:
        if not (self.threshold >= 0 and 0 < self.weber < 10):
            raise ModelParameterError(
                f"sense {self.name}: threshold {self.threshold} must be ≥ 0 and Weber fraction {self.weber} in (0, 10)"
            )

    @property
    def sigma(self) -> float:
        return math.log1p(self.weber) / (math.sqrt(2.0) * 0.6744897501960817)

    def observe(self, magnitude: float, rng: np.random.Generator) -> float:
        """One noisy observation of a physical magnitude (0 when not felt)."""
        if not (magnitude > 0 and math.isfinite(magnitude)):
            return 0.0
        seen = magnitude * math.exp(self.sigma * rng.standard_normal())
        return seen if seen >= self.threshold else 0.0
