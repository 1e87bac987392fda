"""The baseline palpation controllers of seed 000: no feedback, linear (eq. 1), piecewise-discrete.

All read the calibrated sensor force (``force_n``) and command the pneumatic balloon and the vibration
motor as control amounts 0-100 (``balloon_pct``, ``vibration_pct``). Like the study's code, the linear and
piecewise maps act on the mean force over the last ``window_s`` seconds (BHF code: a 0.2 s buffer of
sensor samples). None of them builds any afferent model (``needs()`` is empty).

Parameter sources: ``ouyangqq/Bioinspired_Haptic_Feedback_sys`` @59941bb ``actuators_sensors.py``
("BHF code"; ``research/capr.md`` §3).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping
from typing import Any, ClassVar

from studyctl.errors import ModelParameterError
from studyctl.plugins.interfaces import Controller, Observation, Scene
from studyctl.plugins.params import Param, validate_params

OUTPUTS = ("balloon_pct", "vibration_pct")


class PalpationController(Controller):
    """Shared plumbing: parameter checking, the sensor channel, the force window, invalid samples."""

    outputs: ClassVar[tuple[str, ...]] = OUTPUTS
    PARAMS: ClassVar[tuple[Param, ...]] = (
        Param("sensor_channel", "force_n", kind=str, source="studyctl palpation devices", doc="force input"),
        Param("rate_hz", 50.0, 1.0, 2000.0, unit="Hz", source="paper: sensor updated at a rate near 50 Hz"),
    )

    def __init__(self, params: Mapping[str, Any] | None = None, scene: Scene | None = None) -> None:
        checked = validate_params(f"{self.name} controller", params, self.PARAMS)
        super().__init__(checked, scene)
        self.rate_hz = float(checked["rate_hz"])
        self.channel = checked["sensor_channel"]
        self.validate()
        self.reset()

    def validate(self) -> None:
        """Cross-parameter checks (raise ModelParameterError)."""

    def reset(self) -> None:
        self._last_force = 0.0

    def force(self, obs: Observation) -> float | None:
        """The sensor force of this tick, or None when it is missing or not finite (a sensor fault)."""
        if self.channel not in obs.values:
            known = ", ".join(sorted(obs.values)) or "none"
            raise ModelParameterError(
                f"{self.name} controller: the device gives no channel {self.channel!r} (it gives: {known}); "
                "set the controller's sensor_channel"
            )
        value = obs.values[self.channel]
        if type(value) is float and value - value == 0.0:  # the usual tick: a finite float, kept as it is
            self._last_force = value
            return value
        if not isinstance(value, int | float) or not math.isfinite(value):
            return None
        self._last_force = float(value)
        return self._last_force

    @staticmethod
    def safe() -> dict[str, float]:
        return {"balloon_pct": 0.0, "vibration_pct": 0.0}


class _Windowed(PalpationController):
    """Controllers acting on the mean force over the last ``window_s`` seconds."""

    PARAMS = PalpationController.PARAMS + (
        Param("window_s", 0.2, 0.0, 5.0, unit="s", source="BHF code: sampled_T = 0.2 s buffer"),
    )

    def reset(self) -> None:
        super().reset()
        n = max(1, int(round(self.params["window_s"] * self.rate_hz)))
        self._window: deque[float] = deque(maxlen=n)
        self._sum = 0.0

    def mean_force(self, obs: Observation) -> float | None:
        f = self.force(obs)
        if f is None:
            return None  # an invalid sample never enters the window
        if len(self._window) == self._window.maxlen:
            self._sum -= self._window[0]
        self._window.append(f)
        self._sum += f
        return self._sum / len(self._window)


class NoFeedback(PalpationController):
    """No haptic feedback: both actuators stay off (visual feedback only)."""

    name = "none"

    def step(self, obs: Observation) -> dict[str, float]:
        return self.safe()


class LinearController(_Windowed):
    """Linear haptic feedback, eq. 1: ``c = (s − s_min)/(s_max − s_min)·(c_max − c_min) + c_min`` per actuator.

    The output is kept in the actuator's dynamic range ``[c_min, c_max]`` ("converted the sensor signal
    linearly to the control amount of the actuator in its dynamic range"). Defaults from the BHF code:
    s_min = −0.0381 N (the calibration offset), s_max = 2 N, balloon 36-99, vibration 24-99; c_min is
    where each actuator starts to act, so at rest the balloon gives 0 psi and the motor does not turn.
    """

    name = "linear"
    PARAMS = _Windowed.PARAMS + (
        Param("s_min_n", -0.0381, -1.0, 10.0, unit="N", source="BHF code sensor_down = px0"),
        Param("s_max_n", 2.0, -1.0, 10.0, unit="N", source="BHF code sensor_up"),
        Param("balloon_c_min", 36.0, 0.0, 100.0, source="BHF code pneumatic_down"),
        Param("balloon_c_max", 99.0, 0.0, 100.0, source="BHF code pneumatic_up"),
        Param("vibration_c_min", 24.0, 0.0, 100.0, source="BHF code vibro_down"),
        Param("vibration_c_max", 99.0, 0.0, 100.0, source="BHF code vibro_up"),
    )

    def validate(self) -> None:
        p = self.params
        if not p["s_max_n"] > p["s_min_n"]:
            raise ModelParameterError(
                f"linear controller: s_max_n ({p['s_max_n']}) must be greater than s_min_n ({p['s_min_n']})"
            )
        for act in ("balloon", "vibration"):
            if not p[f"{act}_c_max"] >= p[f"{act}_c_min"]:
                raise ModelParameterError(
                    f"linear controller: {act}_c_max ({p[f'{act}_c_max']}) must be ≥ {act}_c_min ({p[f'{act}_c_min']})"
                )
        # eq. 1's constants for the tick: the sensor range and each actuator's (output channel, c_min, c_max)
        self._s_min, self._s_span = p["s_min_n"], p["s_max_n"] - p["s_min_n"]
        self._ranges = tuple((f"{act}_pct", p[f"{act}_c_min"], p[f"{act}_c_max"]) for act in ("balloon", "vibration"))

    def step(self, obs: Observation) -> dict[str, float]:
        s = self.mean_force(obs)
        if s is None:
            return self.safe()
        x = (s - self._s_min) / self._s_span
        return {channel: min(max(x * (hi - lo) + lo, lo), hi) for channel, lo, hi in self._ranges}


class PiecewiseController(_Windowed):
    """Piecewise-discrete haptic feedback: the window-mean force picks a step of (balloon, vibration) levels.

    Defaults are the BHF code's ``current_controlling``: thresholds at the calibrated forces of ADC
    200/250/300/700 (÷4) = 0.4307, 0.5696, 0.7189, 2.3846 N and levels [0,0], [30,0], [50,30], [80,70],
    [99,99]. A force exactly at the top threshold falls in the top step (the BHF code drops it).
    """

    name = "piecewise"
    PARAMS = _Windowed.PARAMS + (
        Param("thresholds_n", (0.4307, 0.5696, 0.7189, 2.3846), kind=tuple, unit="N",
              source="BHF code rgbuf = presure_from_AD([200,250,300,700]/4)"),
        Param("levels", ((0, 0), (30, 0), (50, 30), (80, 70), (99, 99)), kind=tuple,
              source="BHF code current_controlling"),
    )

    def validate(self) -> None:
        th = self.params["thresholds_n"]
        levels = self.params["levels"]
        if not all(isinstance(v, int | float) and math.isfinite(v) for v in th) or list(th) != sorted(set(th)):
            raise ModelParameterError(f"piecewise controller: thresholds_n {list(th)} must be increasing numbers")
        if len(levels) != len(th) + 1:
            raise ModelParameterError(
                f"piecewise controller: {len(th)} thresholds need {len(th) + 1} levels, got {len(levels)}"
            )
        for lv in levels:
            if (
                not isinstance(lv, list | tuple)
                or len(lv) != 2
                or not all(isinstance(v, int | float) and 0 <= v <= 100 for v in lv)
            ):
                raise ModelParameterError(
                    f"piecewise controller: level {lv!r} must be [balloon, vibration] with values in 0..100"
                )
        self._levels = [(float(b), float(v)) for b, v in levels]
        self._th = [float(v) for v in th]

    def step(self, obs: Observation) -> dict[str, float]:
        s = self.mean_force(obs)
        if s is None:
            return self.safe()
        k = sum(1 for th in self._th if s >= th)
        b, v = self._levels[k]
        return {"balloon_pct": b, "vibration_pct": v}
