"""A participant's plan as it is stored: :class:`PlanEntry` per trial and the whole :class:`Schedule`, with their
JSON form (what the store keeps) and table form. How a protocol is expanded into one is
:mod:`studyctl.protocol.schedule`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # pandas (+pyarrow, ~90 MB) is imported where a table is built: loading or checking a
    import pandas as pd  # protocol stays a small process (issue 19: hostile files within 200 MB)

PLAN_COLUMNS = (
    "trial",
    "position",
    "block",
    "condition",
    "repetition",
    "placement",
    "orientation_deg",
    "time_limit_s",
    "familiarisation_max_s",
    "break_before_s",
    "questionnaires_after",
)


@dataclass(frozen=True, slots=True)
class PlanEntry:
    """One planned trial of a participant.

    Attributes
    ----------
    trial
        1-based index of the trial in the participant's plan.
    position
        1-based position of this trial's condition in the block's condition order.
    block
        1-based block (one pass through the condition order).
    condition
        Condition id.
    repetition
        1-based repetition of the condition within its block.
    placement
        ``((item, site), …)``: the 1-based site (hole) of each scene item, or None without placement.
    orientation_deg
        Orientation of the phantom/model in degrees, or None without orientation randomisation.
    time_limit_s
        Hard time limit of the trial (None: no limit).
    familiarisation_max_s
        Familiarisation offered before this trial (at most this long; None: none).
    break_before_s
        Break before this trial, in seconds.
    questionnaires_after
        Instrument ids administered after this trial, in protocol order.
    """

    trial: int
    position: int
    block: int
    condition: str
    repetition: int
    placement: tuple[tuple[str, int], ...] | None
    orientation_deg: float | None
    time_limit_s: float | None
    familiarisation_max_s: float | None
    break_before_s: float
    questionnaires_after: tuple[str, ...]

    @property
    def placement_map(self) -> dict[str, int]:
        """Placement as ``{item: site}`` (empty without placement)."""
        return dict(self.placement or ())

    def scene_placement(self) -> dict[str, Any]:
        """What :meth:`Scene.build` receives as ``placement``: ``{"sites": {...}, "orientation_deg": ...}``."""
        return {"sites": self.placement_map, "orientation_deg": self.orientation_deg}

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready dict (placement as ``{item: site}``)."""
        return {
            "trial": self.trial,
            "position": self.position,
            "block": self.block,
            "condition": self.condition,
            "repetition": self.repetition,
            "placement": None if self.placement is None else dict(self.placement),
            "orientation_deg": self.orientation_deg,
            "time_limit_s": self.time_limit_s,
            "familiarisation_max_s": self.familiarisation_max_s,
            "break_before_s": self.break_before_s,
            "questionnaires_after": list(self.questionnaires_after),
        }

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> PlanEntry:
        """Inverse of :meth:`to_json`."""
        placement = data.get("placement")
        return cls(
            trial=int(data["trial"]),
            position=int(data["position"]),
            block=int(data["block"]),
            condition=str(data["condition"]),
            repetition=int(data["repetition"]),
            placement=None if placement is None else tuple((str(k), int(v)) for k, v in placement.items()),
            orientation_deg=_optional_float(data, "orientation_deg"),
            time_limit_s=_optional_float(data, "time_limit_s"),
            familiarisation_max_s=_optional_float(data, "familiarisation_max_s"),
            break_before_s=float(data.get("break_before_s", 0.0)),
            questionnaires_after=tuple(data.get("questionnaires_after", ())),
        )


def _optional_float(data: dict[str, Any], key: str) -> float | None:
    value = data.get(key)
    return None if value is None else float(value)


def format_placement(placement: tuple[tuple[str, int], ...] | None) -> str:
    """``soft=3;medium=5;hard=1`` (empty string without placement)."""
    return "" if placement is None else ";".join(f"{item}={site}" for item, site in placement)


@dataclass(frozen=True)
class Schedule:
    """A participant's whole ordered plan, with everything needed to re-derive it.

    ``order`` is the condition order of block 1; ``sequence`` the index of that order among the
    scheme's sequences (None for the ``random`` scheme); ``questionnaires_start`` the instruments given
    before the first trial.
    """

    protocol_id: str
    protocol_sha256: str
    algorithm_version: int
    seed: int
    stratum: str
    slot: int
    sequence: int | None
    order: tuple[str, ...]
    questionnaires_start: tuple[str, ...]
    entries: tuple[PlanEntry, ...]

    def to_frame(self) -> pd.DataFrame:
        """One row per planned trial with the columns of :data:`PLAN_COLUMNS`."""
        import pandas as pd

        rows = [
            (
                e.trial,
                e.position,
                e.block,
                e.condition,
                e.repetition,
                format_placement(e.placement),
                e.orientation_deg,
                e.time_limit_s,
                e.familiarisation_max_s,
                e.break_before_s,
                ",".join(e.questionnaires_after),
            )
            for e in self.entries
        ]
        return pd.DataFrame(rows, columns=list(PLAN_COLUMNS))

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready dict: what the store keeps as the participant's schedule."""
        return {
            "protocol_id": self.protocol_id,
            "protocol_sha256": self.protocol_sha256,
            "algorithm_version": self.algorithm_version,
            "seed": self.seed,
            "stratum": self.stratum,
            "slot": self.slot,
            "sequence": self.sequence,
            "order": list(self.order),
            "questionnaires_start": list(self.questionnaires_start),
            "entries": [e.to_json() for e in self.entries],
        }

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> Schedule:
        """Inverse of :meth:`to_json`."""
        return cls(
            protocol_id=str(data["protocol_id"]),
            protocol_sha256=str(data["protocol_sha256"]),
            algorithm_version=int(data["algorithm_version"]),
            seed=int(data["seed"]),
            stratum=str(data["stratum"]),
            slot=int(data["slot"]),
            sequence=None if data.get("sequence") is None else int(data["sequence"]),
            order=tuple(data["order"]),
            questionnaires_start=tuple(data.get("questionnaires_start", ())),
            entries=tuple(PlanEntry.from_json(e) for e in data["entries"]),
        )
