"""Models of the seed-000 palpation hardware: force sensor + ADC, pneumatic balloon, vibration motor.

Pure functions and small frozen parameter sets; the simulated device and the driver-board emulator
both use them. Where a value comes from the public code of the study
(``ouyangqq/Bioinspired_Haptic_Feedback_sys`` @59941bb, "BHF code") or from the paper, the source is
written beside it; values no source gives are marked **chosen** with the reason.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

import numpy as np

from studyctl.errors import ModelParameterError

# --------------------------------------------------------------------------------------------------
# Force sensor (FlexiForce A201) read through a 10-bit ADC
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class SensorCalibration:
    """Calibration curve of the force sensor: ADC counts → force in newtons.

    ``F = c3·a³ + c2·a² + c1·a + c0`` with ``a = counts / counts_per_unit``.

    Sources: the cubic and its coefficients are the BHF code's ``presure_from_AD``
    (``actuators_sensors.py``: 7e-8, 2e-5, 0.0082, offset −0.0381 N). The paper states a 10-bit ADC
    (Fig. 1b); the BHF code's polynomial takes an 8-bit value (its piecewise thresholds are written as
    ``[200, 250, 300, 700] / 4``), so a 10-bit count is divided by 4 (inferred, as in
    ``research/capr.md``). Sensing area: the A201's 9.53 mm diameter (Tekscan datasheet).
    """

    c3: float = 7e-8
    c2: float = 2e-5
    c1: float = 0.0082
    c0: float = -0.0381
    counts_per_unit: float = 4.0
    adc_bits: int = 10
    sensing_diameter_mm: float = 9.53

    @property
    def adc_max(self) -> int:
        return (1 << self.adc_bits) - 1

    def force(self, counts: float | np.ndarray) -> float | np.ndarray:
        """Force (N) for ADC counts; raises ModelParameterError for counts outside ``0..adc_max`` or NaN."""
        arr = np.asarray(counts, dtype=float)
        bad = ~np.isfinite(arr) | (arr < 0) | (arr > self.adc_max)
        if np.any(bad):
            first = arr[bad].flat[0] if arr.ndim else float(arr)
            raise ModelParameterError(
                f"force sensor: ADC value {first!r} is outside the {self.adc_bits}-bit range 0..{self.adc_max}; "
                "check the sensor cable and the board's ADC configuration"
            )
        a = arr / self.counts_per_unit
        out = ((self.c3 * a + self.c2) * a + self.c1) * a + self.c0
        return float(out) if out.ndim == 0 else out

    @property
    def force_range_n(self) -> tuple[float, float]:
        return float(self.force(0)), float(self.force(self.adc_max))

    def counts(self, force_n: float | np.ndarray) -> int | np.ndarray:
        """The ADC count a force produces: inverse of :meth:`force`, rounded, saturating at 0 and adc_max.

        The curve is strictly increasing on the ADC range (all coefficients ≥ 0 but the offset), so the
        inverse is found by interpolation in the 1024-point table of :meth:`force`.
        """
        table = self._table()
        f = np.asarray(force_n, dtype=float)
        if np.any(~np.isfinite(f)):
            raise ModelParameterError(f"force sensor: force {force_n!r} is not a finite number")
        idx = np.interp(f, table, np.arange(table.size))
        out = np.clip(np.rint(idx), 0, self.adc_max).astype(int)
        return int(out) if out.ndim == 0 else out

    def force_of_count(self, count: int) -> float:
        """Scalar fast path of :meth:`force` for one integer count already known to be in range."""
        a = count / self.counts_per_unit
        return ((self.c3 * a + self.c2) * a + self.c1) * a + self.c0

    def count_of_force(self, force_n: float) -> int:
        """Scalar fast path of :meth:`counts`: nearest ADC count for a finite force, saturating."""
        return count_in_table(self.count_table(), force_n, self.adc_max)

    def count_table(self) -> list[float]:
        """The force (N) of every ADC count, as a list for :func:`count_in_table` (cached per calibration)."""
        cached = _LISTS.get(self)
        if cached is None:
            cached = _LISTS[self] = self._table().tolist()
        return cached

    def _table(self) -> np.ndarray:
        table = _TABLES.get(self)
        if table is None:
            table = np.asarray(self.force(np.arange(self.adc_max + 1)), dtype=float)
            if np.any(np.diff(table) <= 0):
                raise ModelParameterError("force sensor: calibration curve is not increasing over the ADC range")
            _TABLES[self] = table
        return table

    def sensing_area_m2(self) -> float:
        return math.pi * (self.sensing_diameter_mm * 1e-3 / 2) ** 2

    def pressure_kpa(self, force_n: float) -> float:
        """Mean pressure (kPa) over the sensing area for a force (N)."""
        return force_n / self.sensing_area_m2() / 1e3


def count_in_table(table: list[float], force_n: float, adc_max: int) -> int:
    """The nearest ADC count for a finite force in ``table`` (:meth:`SensorCalibration.count_table`), saturating
    at 0 and ``adc_max``: what a device calls every tick with its calibration's table in hand."""
    i = bisect.bisect_left(table, force_n)
    if i <= 0:
        return 0
    if i >= len(table):
        return adc_max
    lo, hi = table[i - 1], table[i]
    return i if (force_n - lo) >= (hi - force_n) else i - 1


_TABLES: dict[SensorCalibration, np.ndarray] = {}
_LISTS: dict[SensorCalibration, list[float]] = {}
A201 = SensorCalibration()


def first_order_step(value: float, target: float, dt: float, tau_s: float) -> float:
    """``value`` after ``dt`` seconds of an exact first-order lag (time constant ``tau_s``) towards ``target``.

    ``tau_s <= 0`` jumps to the target at once; ``dt <= 0`` (no time passed) keeps ``value``.
    """
    if tau_s <= 0 or dt <= 0:
        return target if dt > 0 or tau_s <= 0 else value
    return target + (value - target) * math.exp(-dt / tau_s)


def lag_decay(dt: float, tau_s: float) -> float | None:
    """The factor ``exp(-dt/tau_s)`` of :func:`first_order_step` for a step of ``dt`` > 0 seconds (None: ``tau_s
    <= 0``, a jump to the target), to be reused by :func:`decayed_step` while the step length repeats."""
    return math.exp(-dt / tau_s) if tau_s > 0 else None


def decayed_step(value: float, target: float, decay: float | None) -> float:
    """:func:`first_order_step` for ``dt`` > 0 with its :func:`lag_decay` factor given: the same value."""
    return target if decay is None else target + (value - target) * decay


class _FirstOrderActuator:
    """An actuator whose state lags its static target by a first-order lag of time constant ``tau_s``.

    A subclass names the target: ``_target(control)``, the state the control settles at (the balloon's pressure,
    the motor's normalised speed). One place for the three steps both actuators take.
    """

    tau_s: float

    def _target(self, control: float) -> float:
        raise NotImplementedError

    def step(self, state: float, control: float, dt: float) -> float:
        """The state after ``dt`` seconds at ``control``, starting from ``state`` (exact first-order step)."""
        return first_order_step(state, self._target(control), dt, self.tau_s)

    def decay(self, dt: float) -> float | None:
        return lag_decay(dt, self.tau_s)

    def step_decayed(self, state: float, control: float, decay: float | None) -> float:
        """:meth:`step` for ``dt`` > 0 given its :meth:`decay` factor (a loop of equal ticks computes it once)."""
        return decayed_step(state, self._target(control), decay)


# --------------------------------------------------------------------------------------------------
# Pneumatic balloon: pressure against control amount (solenoid valve opening, 0-100)
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class BalloonModel(_FirstOrderActuator):
    """Static curve and first-order dynamics of the pneumatic balloon.

    Static: ``psi = slope·(c − dead_zone)`` above the dead zone, 0 below, never above the regulator.
    Sources: slope 0.25 psi per control unit and dead zone 36 are the BHF code's fit
    (``[Fig.1c]_Charateristics_of_actuators.py``: ``PSI = 0.25·C − 9`` for C > 36); the 20 psi regulator
    is the paper's ("maximum pressure ... set to 20 PSI"). ``tau_s`` is **chosen** (50 ms, a typical
    solenoid-valve/balloon fill time; no source gives it).
    """

    slope_psi: float = 0.25
    dead_zone: float = 36.0
    regulator_psi: float = 20.0
    tau_s: float = 0.05

    def static_psi(self, control: float) -> float:
        if not math.isfinite(control):
            return 0.0
        return min(max(self.slope_psi * (control - self.dead_zone), 0.0), self.regulator_psi)

    # the lag's target: the pressure the valve opening settles at (step() lags pressure)
    _target = static_psi


# PSI → N/mm²; the paper's K_psi (6.896e-3), i.e. 0.454 kgf·9.8 / 25.4² as in the BHF code.
K_PSI_N_PER_MM2 = 6.896e-3


# --------------------------------------------------------------------------------------------------
# Vibration motor (8 mm coin ERM): frequency and acceleration against PWM duty (0-100)
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class VibrationMotorModel(_FirstOrderActuator):
    """Coin eccentric-rotating-mass motor: frequency and amplitude rise together with PWM duty.

    The paper: amplitude and frequency "cannot be modulated independently: both increase as function of
    the driving voltage (PWM duty)", and the BHF code fits each with a quadratic in the duty — but its
    coefficients and data are not in the public repository. **Chosen** here: no motion below
    ``start_duty`` (24, by analogy with the balloon, whose dead zone ends at the linear controller's
    c_min; 24 is the BHF code's vibration c_min), then with ``x = (duty − start)/(100 − start)``:
    ``f = f_max·(1.3x − 0.3x²)`` (concave, speed saturating) and ``a = a_max·x²`` (ERM force ∝ speed²),
    with f_max = 250 Hz and a_max = 12 m/s² inside the BHF plot axes (≤ 400 Hz, ≤ 16 m/s²). ``tau_s``
    (spin-up, 40 ms) is **chosen** from the usual 30–80 ms of coin ERMs.
    """

    start_duty: float = 24.0
    f_max_hz: float = 250.0
    a_max_ms2: float = 12.0
    tau_s: float = 0.04

    def _x(self, duty: float) -> float:
        if not math.isfinite(duty):
            return 0.0
        return min(max((duty - self.start_duty) / (100.0 - self.start_duty), 0.0), 1.0)

    def static(self, duty: float) -> tuple[float, float]:
        """(frequency Hz, acceleration m/s²) at steady state for a PWM duty."""
        return self.output(self._x(duty))

    # the lag's target: the normalised speed x the duty settles at (step() lags x, output() reads it)
    _target = _x

    def output(self, speed: float) -> tuple[float, float]:
        """(frequency Hz, acceleration m/s²) at normalised speed x."""
        x = min(max(speed, 0.0), 1.0)
        return self.f_max_hz * (1.3 * x - 0.3 * x * x), self.a_max_ms2 * x * x
