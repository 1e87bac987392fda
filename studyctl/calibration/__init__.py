"""Calibration of virtual populations to published (or pilot) numbers, and the simulated-vs-published check.

* :func:`simulated_values` — each target's simulated value from a metric table and the plan's test rows;
* :func:`agreement` — simulated vs published per target (direction, band, verdict) and the fractions;
* :func:`distance` — the simulated-method-of-moments distance ``studyctl calibrate`` minimises.

The orchestration (simulate candidates with common random numbers, optimise, write files) is
:mod:`studyctl.workflows.calibrate`.
"""

from studyctl.calibration.agreement import Agreement, AgreementRow, agreement, distance
from studyctl.calibration.simulated import SimulatedStats, SimulatedValue, simulated_values

__all__ = [
    "Agreement",
    "AgreementRow",
    "SimulatedStats",
    "SimulatedValue",
    "agreement",
    "distance",
    "simulated_values",
]
