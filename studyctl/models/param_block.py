"""A model's parameter block taken from a condition's parameter mapping."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import fields
from typing import Any, Self


class ParamBlock:
    """Base of a frozen dataclass of model parameters that checks itself in ``validate(where)``."""

    def validate(self, where: str) -> None:
        """Raise :class:`~studyctl.errors.ModelParameterError` naming ``where``, the field and the value."""

    @classmethod
    def from_mapping(cls, params: Mapping[str, Any], where: str) -> Self:
        """Built from the keys of ``params`` that are this block's fields, then validated. The other keys belong
        to other parts of the same condition (controller, device), so they are left to their owners."""
        names = {f.name for f in fields(cls)}  # type: ignore[arg-type]
        out = cls(**{k: v for k, v in params.items() if k in names})
        out.validate(where)
        return out
