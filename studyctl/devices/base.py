"""The constructor every built-in device shares: validate the declared ``PARAMS``, then :meth:`setup`."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

from studyctl.plugins.interfaces import Device, Scene
from studyctl.plugins.params import Param, validate_params


class ParamDevice(Device):
    """A device whose parameters are declared in ``PARAMS``: the constructor checks them (a bad value is a
    :class:`~studyctl.errors.ModelParameterError` naming ``device NAME``), stores them as ``self.params`` (defaults
    filled in) and calls :meth:`setup` to build the rest."""

    PARAMS: ClassVar[tuple[Param, ...]] = ()

    def __init__(
        self,
        params: Mapping[str, Any] | None = None,
        scene: Scene | None = None,
        rng: np.random.Generator | None = None,
    ) -> None:
        super().__init__(validate_params(f"device {self.name}", params, self.PARAMS), scene, rng)
        self.setup(self.params)

    def setup(self, p: dict[str, Any]) -> None:
        """Build the device from its checked parameters ``p`` (limits, models, buffers)."""
