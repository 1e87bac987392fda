"""The metrics studyctl can compute from a study database: names, units and kinds.

Definitions only (no store access), so that plan validation can check names cheaply.
:mod:`studyctl.analysis.metrics` computes them.

Kinds
-----
continuous
    one number per trial (force, time, error, count of scans).
proportion
    successes out of a number of chances per trial (``value`` = successes, ``denominator`` = chances);
    pooled across participants by summing both, as the papers do for detection probability,
    sensitivity and PPV.
ordinal
    questionnaire codes (Likert), one per item.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

CONTINUOUS = "continuous"
PROPORTION = "proportion"
ORDINAL = "ordinal"
KINDS = (CONTINUOUS, PROPORTION, ORDINAL)


@dataclass(frozen=True)
class MetricDef:
    """A metric's identity and defaults.

    ``level`` names the sub-factor a metric is broken down by (tumour class, nodule, questionnaire
    item), or is None. ``params`` are the defaults an analysis plan may override.
    """

    name: str
    label: str
    unit: str
    kind: str
    description: str
    level: str | None = None
    params: Mapping[str, float | str] = field(default_factory=dict)
    studies: tuple[str, ...] = ()
    #: The least value the metric can take by its definition (0 for counts, times, distances, forces and
    #: fractions); None where the definition sets no bound. Published targets below it are refused.
    minimum: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "params", MappingProxyType(dict(self.params)))


BUILTIN: dict[str, MetricDef] = {
    m.name: m
    for m in (
        MetricDef(
            "localisation_accuracy",
            "Localising accuracy",
            "",
            CONTINUOUS,
            "correct reports / all reports in a trial; a report is correct within `tolerance_cells` grid cells "
            "(Chebyshev distance) of a tumour not already claimed",
            params={"tolerance_cells": 1},
            studies=("bio_inspired_palpation",),
            minimum=0.0,
        ),
        MetricDef(
            "mean_contact_force",
            "Mean force during tumour contact",
            "N",
            CONTINUOUS,
            "mean sensor force over the samples in which the probe presses on a tumour above `threshold_n`",
            params={"threshold_n": 0.5},
            studies=("bio_inspired_palpation",),
            minimum=0.0,
        ),
        MetricDef(
            "tumour_contact_time",
            "Tumour contact time",
            "s",
            CONTINUOUS,
            "time the probe presses on a tumour with force above `threshold_n`",
            params={"threshold_n": 0.5},
            studies=("bio_inspired_palpation",),
            minimum=0.0,
        ),
        MetricDef(
            "completion_time",
            "Completion time",
            "s",
            CONTINUOUS,
            "time from trial start to the participant's finish (or the time limit)",
            studies=("bio_inspired_palpation", "data_driven_palpation"),
            minimum=0.0,
        ),
        MetricDef(
            "detection",
            "Detection probability",
            "",
            PROPORTION,
            "per tumour class: 1 if a report lies within `tolerance_cells` of that tumour, else 0",
            level="tumour_class",
            params={"tolerance_cells": 1},
            studies=("bio_inspired_palpation",),
            minimum=0.0,
        ),
        MetricDef(
            "scans",
            "Number of scans",
            "",
            CONTINUOUS,
            "CT scans the participant requested in the trial (0 where the view is real-time)",
            studies=("needle_insertion",),
            minimum=0.0,
        ),
        MetricDef(
            "duration",
            "Duration",
            "s",
            CONTINUOUS,
            "time to finish the insertion, capped at the trial's time limit",
            studies=("needle_insertion",),
            minimum=0.0,
        ),
        MetricDef(
            "tracking_error",
            "Mean trajectory-tracking error",
            "mm",
            CONTINUOUS,
            "mean distance of the needle tip from the planned straight path over the insertion",
            studies=("needle_insertion",),
            minimum=0.0,
        ),
        MetricDef(
            "targeting_error",
            "Targeting error",
            "mm",
            CONTINUOUS,
            "final distance of the needle tip from the tumour centroid",
            studies=("needle_insertion",),
            minimum=0.0,
        ),
        MetricDef(
            "nodules_found",
            "Nodules found",
            "",
            CONTINUOUS,
            "distinct nodules with a report within the hit radius",
            studies=("data_driven_palpation", "pseudo_haptic_palpation"),
            minimum=0.0,
        ),
        MetricDef(
            "false_reports",
            "False reports",
            "",
            CONTINUOUS,
            "reports farther than the hit radius from every nodule (or repeating a found one)",
            studies=("data_driven_palpation", "pseudo_haptic_palpation"),
            minimum=0.0,
        ),
        MetricDef(
            "sensitivity",
            "Sensitivity",
            "",
            PROPORTION,
            "per nodule: 1 if found, out of 1; pooled over participants (and nodules) it is Se = TP / nodules",
            level="nodule",
            studies=("pseudo_haptic_palpation", "data_driven_palpation"),
            minimum=0.0,
        ),
        MetricDef(
            "ppv",
            "Positive predictive value",
            "",
            PROPORTION,
            "true-positive reports out of all reports; pooled over participants it is PPV = TP / (TP + FP)",
            studies=("pseudo_haptic_palpation", "data_driven_palpation"),
            minimum=0.0,
        ),
        MetricDef(
            "detection_time",
            "Detection time",
            "s",
            CONTINUOUS,
            "time from trial start until the participant declared the search finished",
            studies=("pseudo_haptic_palpation",),
            minimum=0.0,
        ),
        MetricDef(
            "likert",
            "Likert score",
            "",
            ORDINAL,
            "questionnaire answer codes per item (administered after a condition or at the end); `instrument` "
            "selects one instrument ('' for all)",
            level="item",
            params={"instrument": ""},
            studies=("needle_insertion",),
        ),
    )
}
