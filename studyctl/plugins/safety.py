"""The safety layer that stands between every controller and every device.

Minimal version: clamps to channel limits and replaces NaN/inf by the safe value. The plugin issue
extends it with rate limits, ramp-up, the watchdog and fault events.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from studyctl.plugins.interfaces import DeviceLimits


class SafetyLayer:
    def __init__(self, limits: DeviceLimits) -> None:
        self.limits = limits
        self._by_name = {c.name: c for c in limits.outputs}
        self.events: list[dict[str, object]] = []

    def filter(self, command: Mapping[str, float], t: float) -> dict[str, float]:
        out: dict[str, float] = {}
        for name, value in command.items():
            limit = self._by_name.get(name)
            if limit is None:
                continue  # a channel the device does not have is never written
            if not math.isfinite(value):
                self.events.append({"t": t, "kind": "non_finite_command", "channel": name})
                value = limit.safe
            out[name] = min(max(value, limit.low), limit.high)
        return out

    def safe_command(self) -> dict[str, float]:
        return self.limits.safe_command()
