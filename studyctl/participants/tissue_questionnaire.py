"""How the virtual tissue palpator answers questionnaires (seed 003's end question, combined vs force feedback):
from the session's stored trial record, else from its remembered percepts; see
:mod:`studyctl.participants.tissue_palpator`."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np


class Questionnaire:
    """Mixin of :class:`~studyctl.participants.tissue_palpator.VirtualTissuePalpator`: questionnaire answers."""

    def answer(self, item: Mapping[str, Any], rng: np.random.Generator) -> int:
        """A code of the item's scale from the participant's own trials (see the module docstring)."""
        codes = sorted(int(c) for c in (item.get("codes") or [1, 2, 3, 4, 5]))
        key = f"{item.get('id', '')} {item.get('text', '')}".lower()
        if "combin" not in key or "force" not in key:
            return codes[len(codes) // 2]
        record = item.get("history")
        if record is None:
            return self._answer_from_memory(codes, rng)
        both: list[Mapping[str, Any]] = []
        force: list[Mapping[str, Any]] = []
        for row in record:
            if row.get("manual") or not row.get("duration_s"):
                continue
            told = _feedback_named(row)
            if told == {"force", "cursor"}:
                both.append(row)
            elif told == {"force"}:
                force.append(row)
        if not both or not force:
            return codes[0]
        weber = self.params["search_weber"]
        # how much faster spots were found with both feedbacks, as a judged (noisy) log ratio
        judged = math.log(_search_rate(both) / _search_rate(force)) + weber * float(rng.normal())
        steps = int(judged / math.log1p(weber)) if judged > 0 else 0  # in just-noticeable differences
        return codes[min(steps, len(codes) - 1)]

    def _answer_from_memory(self, codes: list[int], rng: np.random.Generator) -> int:
        """Without a stored record: from remembered percepts (stronger evidence with both cues perceived?)."""
        felt = [e for e in self.experience if not e["direct"] and math.isfinite(e["z_max"]) and e["z_max"] > 0]
        both = [e["z_max"] for e in felt if {"force", "cursor"} <= set(e["cues"])]
        force = [e["z_max"] for e in felt if e["cues"] == ["force"]]
        if not both or not force:
            return codes[0]
        weber = self.params["visual_weber"]
        judged = math.log(float(np.mean(both)) / float(np.mean(force))) + weber * float(rng.normal())
        steps = int(judged / math.log1p(weber)) if judged > 0 else 0
        return codes[min(steps, len(codes) - 1)]


def _feedback_named(row: Mapping[str, Any]) -> set[str]:
    """The feedbacks a trial's condition was introduced with (its label, else its id): force, cursor or both."""
    name = str(row.get("label") or row.get("condition") or "").lower()
    told = set()
    if "force" in name:
        told.add("force")
    if "pseudo" in name or "cursor" in name:
        told.add("cursor")
    return told


def _search_rate(rows: list[Mapping[str, Any]]) -> float:
    """Spots found per second of searching over the trials (one added, so an empty search still counts)."""
    found = sum(float(r.get("reports") or 0) + 1.0 for r in rows)
    return found / sum(float(r["duration_s"]) for r in rows)
