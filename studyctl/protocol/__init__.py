"""Protocols: the strict YAML language, counterbalancing, and deterministic schedule expansion.

Public API (other packages import from here):

* :func:`load_protocol` / :func:`load_protocol_text` / :func:`check_protocol` / :func:`resolve_protocol`
* :class:`Protocol` and its sections (:class:`Condition`, :class:`TrialTemplate`, :class:`SceneSpec`,
  :class:`Instrument`, :class:`Administration`, :class:`ResumePolicy`, …)
* :func:`expand_schedule`, :class:`Planner`, :class:`Schedule`, :class:`PlanEntry`,
  :data:`SCHEDULE_ALGORITHM_VERSION`
* :func:`schedule_balance`, :class:`BalanceReport`, and the schemes in
  :mod:`studyctl.protocol.counterbalance`

Enrollment writes a protocol's schedule to the store, so it lives in the store package (above protocol):
:mod:`studyctl.store.enrollment` (``enroll``, ``replan``, ``study_protocol``).
"""

from studyctl.problems import Mark, Problem
from studyctl.protocol.counterbalance import BalanceReport, balance_report
from studyctl.protocol.loader import check_protocol, find_problems, load_protocol, load_protocol_text, resolve_protocol
from studyctl.protocol.schedule import (
    SCHEDULE_ALGORITHM_VERSION,
    Planner,
    allocate_strata,
    expand_many,
    expand_schedule,
    schedule_balance,
    schedule_rows,
)
from studyctl.protocol.schema import (
    Administration,
    Condition,
    Counterbalance,
    Design,
    Devices,
    Familiarisation,
    Grid,
    Instrument,
    Item,
    Orientation,
    ParticipantsSpec,
    Placement,
    PluginRef,
    Protocol,
    ReportSpec,
    ResumePolicy,
    Scale,
    SceneSpec,
    Stratum,
    StudyMeta,
    TrialTemplate,
)
from studyctl.protocol.stored_plan import PlanEntry, Schedule

__all__ = [
    "SCHEDULE_ALGORITHM_VERSION",
    "Administration",
    "BalanceReport",
    "Condition",
    "Counterbalance",
    "Design",
    "Devices",
    "Familiarisation",
    "Grid",
    "Instrument",
    "Item",
    "Mark",
    "Orientation",
    "ParticipantsSpec",
    "PlanEntry",
    "Placement",
    "Planner",
    "PluginRef",
    "Problem",
    "Protocol",
    "ReportSpec",
    "ResumePolicy",
    "Scale",
    "SceneSpec",
    "Schedule",
    "Stratum",
    "StudyMeta",
    "TrialTemplate",
    "allocate_strata",
    "balance_report",
    "check_protocol",
    "expand_many",
    "expand_schedule",
    "find_problems",
    "load_protocol",
    "load_protocol_text",
    "resolve_protocol",
    "schedule_balance",
    "schedule_rows",
]
