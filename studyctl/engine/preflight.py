"""Preflight: before a session starts, check every plugin its conditions need is available.

A plugin is available when its entry point imports and yields a class of the right kind. A device class
may also offer ``available(params) -> str | None`` (a classmethod or staticmethod) to probe its hardware
without opening it; a returned string says why the device is not ready.
"""

from __future__ import annotations

from dataclasses import dataclass

import pandas as pd

from studyctl.engine.factory import MANUAL_TOUCH_DEVICE, PluginFactory
from studyctl.engine.plan import SessionPlan
from studyctl.errors import PluginError, SessionError
from studyctl.plugins.interfaces import Participant


@dataclass(frozen=True)
class PreflightCheck:
    kind: str  # scene, controller, device, participant
    name: str
    needed_by: str  # what in the plan needs it
    ok: bool
    detail: str


@dataclass(frozen=True)
class PreflightReport:
    """The checks of one preflight; ``missing`` lists the failed ones."""

    checks: tuple[PreflightCheck, ...]

    COLUMNS = ("kind", "name", "needed_by", "ok", "detail")

    @property
    def ok(self) -> bool:
        return all(c.ok for c in self.checks)

    @property
    def missing(self) -> tuple[PreflightCheck, ...]:
        return tuple(c for c in self.checks if not c.ok)

    def to_frame(self) -> pd.DataFrame:
        return pd.DataFrame([(c.kind, c.name, c.needed_by, c.ok, c.detail) for c in self.checks],
                            columns=list(self.COLUMNS))

    def raise_if_missing(self) -> None:
        if self.ok:
            return
        lines = "; ".join(f"{c.kind} {c.name!r} (needed by {c.needed_by}): {c.detail}" for c in self.missing)
        raise SessionError(f"preflight failed, {len(self.missing)} plugin(s) not available: {lines}. "
                           "Install the missing plugin package or fix the device, then run again")


def preflight(
    plan: SessionPlan, factory: PluginFactory, *, virtual: bool, person_participant: bool = True
) -> PreflightReport:
    """Check the plugins the plan's conditions need.

    Parameters
    ----------
    plan
        The session plan (its conditions, scene and devices).
    factory
        Where plugins come from (entry points in production).
    virtual
        Virtual participant: the simulated device and the protocol's virtual participant are needed;
        otherwise the hardware device (or the simulated one when the protocol names no hardware).
    person_participant
        For people: the ``person`` participant plugin is needed too.
    """
    needed: dict[tuple[str, str], list[str]] = {}

    def need(kind: str, name: str | None, by: str) -> None:
        if name:
            needed.setdefault((kind, name), []).append(by)

    used = {s.condition for s in plan.trials()}
    if plan.scene and any(not plan.conditions[c].manual or virtual for c in used):
        need("scene", plan.scene, "the trials")
    for cid in sorted(used):
        cond = plan.conditions[cid]
        if cond.manual and not virtual:
            continue
        need("controller", None if cond.manual else cond.controller, f"condition {cid}")
    device = plan.simulated_device if virtual else (plan.hardware_device or plan.simulated_device)
    device_params = dict((device or {}).get("params", {}))
    if any(not plan.conditions[c].manual for c in used):
        if not device:
            raise SessionError(f"the plan of study {plan.study!r} names no device")
        need("device", device["plugin"], "the trials (virtual)" if virtual else "the trials")
    if virtual:  # a virtual participant palpates manual conditions with the simulated bare finger
        for cid in sorted(c for c in used if plan.conditions[c].manual):
            need("device", MANUAL_TOUCH_DEVICE, f"condition {cid} (manual, virtual participant)")
    if virtual:
        if not plan.virtual_participant:
            raise SessionError(f"protocol of study {plan.study!r} names no virtual participant "
                               "(participants.virtual); it cannot be run with --virtual")
        need("participant", plan.virtual_participant["plugin"], "the virtual participant")
    elif person_participant:
        need("participant", "person", "the person at the terminal")
    checks = []
    for (kind, name), by in needed.items():
        try:
            cls = factory.load(kind, name)
        except PluginError as exc:
            checks.append(PreflightCheck(kind, name, ", ".join(by), False, str(exc)))
            continue
        detail = "available"
        ok = True
        if kind == "participant" and virtual and plan.instruments and _cannot_answer(cls):
            asked = ", ".join(sorted(plan.instruments))
            checks.append(PreflightCheck(kind, name, ", ".join(by), False,
                                         f"cannot answer questionnaires (no answer() method) but the protocol "
                                         f"administers {asked}"))
            continue
        probe = getattr(cls, "available", None) if kind == "device" else None
        if callable(probe):
            try:
                problem = probe(device_params)
            except Exception as exc:  # a probe that crashes means the device is not usable
                problem = f"{type(exc).__name__}: {exc}"
            if problem:
                ok, detail = False, str(problem)
        checks.append(PreflightCheck(kind, name, ", ".join(by), ok, detail))
    return PreflightReport(tuple(checks))


def _cannot_answer(cls: type) -> bool:

    return getattr(cls, "answer", None) is Participant.answer
