"""What a participant answering a questionnaire may base its answers on (the trials it did, in plan order)."""

from __future__ import annotations

from typing import Any

from studyctl.engine.plan import SessionPlan, Step
from studyctl.engine.recorder import SessionState


def questionnaire_context(state: SessionState, step: Step) -> dict[str, Any]:
    """The context a questionnaire step's items are asked in: where it is in the plan, the completed trials of its
    condition (all of them for an end-of-study questionnaire) and the whole completed history."""
    plan = state.plan
    return {
        "position": step.position,
        "when": step.data.get("when"),
        "condition": step.condition,
        "block": step.block,
        "trials": [
            dict(t.outcome) for t in state.trials
            if t.status == "completed" and (step.condition is None or t.condition == step.condition)
        ],
        # every completed trial in plan order: a participant may base answers on it instead of memory,
        # so a resumed session answers exactly as an uninterrupted one
        "history": [
            {"condition": t.condition, **_told(plan, t.condition), **dict(t.outcome)}
            for t in _in_plan_order(state) if t.status == "completed"
        ],
    }


def _told(plan: SessionPlan, condition: str | None) -> dict[str, Any]:
    """What the participant was told about a trial's condition (its name, the view it had, whether it was
    manual): known to a person, and needed to judge one scenario against another from the record."""
    spec = plan.conditions.get(condition) if condition else None
    if spec is None:
        return {}
    return {"label": spec.label or spec.id, "visual": spec.visual, "manual": spec.manual}


def _in_plan_order(state: SessionState) -> list:
    order = {s.position: i for i, s in enumerate(state.plan.steps)}
    return sorted(state.trials, key=lambda t: (order.get(t.position, 0), t.attempt))
