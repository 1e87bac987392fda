"""How the engine obtains plugin instances: a small factory interface and the entry-point implementation.

The engine asks a :class:`PluginFactory` for a scene, a controller, a device and a participant by
entry-point name. :class:`EntryPointFactory` resolves names through the plugin registry
(:mod:`studyctl.plugins`), so built-ins and third-party plugins are treated alike; tests pass a
:class:`MappingFactory` with classes of their own.
"""

from __future__ import annotations

import inspect
from collections.abc import Mapping
from typing import Any, Protocol

import numpy as np

from studyctl.errors import PluginError
from studyctl.plugins import registry
from studyctl.plugins.interfaces import Controller, Device, Participant, Scene

# A virtual participant in a manual condition (a person palpates the real phantom there) palpates the trial's
# scene with this simulated bare finger: the tissue's own reaction force, no device, no screen.
MANUAL_TOUCH_DEVICE = "direct_touch"


class PluginFactory(Protocol):
    def load(self, kind: str, name: str) -> type:
        """The plugin class ``name`` of ``kind`` (controller, device, scene, participant)."""

    def known(self, kind: str) -> list[str]: ...


def _call_with_supported(cls: type, **kwargs: Any) -> Any:
    """Construct ``cls`` passing only the keyword arguments its constructor accepts.

    Device and participant constructors differ between plugins (a hardware adapter takes no scene);
    this keeps the engine from guessing positional orders.
    """
    try:
        sig = inspect.signature(cls)
    except (TypeError, ValueError):
        return cls()
    params = sig.parameters
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        return cls(**kwargs)
    return cls(**{k: v for k, v in kwargs.items() if k in params})


def build_scene(
    factory: PluginFactory,
    name: str,
    spec: Mapping[str, Any],
    placement: Mapping[str, Any],
    needs: frozenset[str],
    rng: np.random.Generator,
) -> Scene:
    cls = factory.load("scene", name)
    return cls.build(spec, placement, needs, rng)


def build_controller(
    factory: PluginFactory, name: str, params: Mapping[str, Any], scene: Scene | None
) -> Controller:
    cls = factory.load("controller", name)
    return cls(params, scene)


def build_device(
    factory: PluginFactory, name: str, params: Mapping[str, Any], scene: Scene | None, rng: np.random.Generator
) -> Device:
    cls = factory.load("device", name)
    return _call_with_supported(cls, params=dict(params), scene=scene, rng=rng)


def build_participant(factory: PluginFactory, name: str, params: Mapping[str, Any]) -> Participant:
    cls = factory.load("participant", name)
    return _call_with_supported(cls, params=dict(params))


def controller_needs(factory: PluginFactory, name: str | None, params: Mapping[str, Any], visual: str) -> frozenset:
    """Scene parts the condition uses: the controller's needs plus the visual channel's."""
    needs: set[str] = set()
    if name is not None:
        needs |= set(factory.load("controller", name).needs(params))
    if visual != "none":
        needs.add("view")
    return frozenset(needs)


class EntryPointFactory:
    """Plugins from the ``studyctl.*`` entry-point groups via :mod:`studyctl.plugins.registry`
    (the same path for built-ins and third parties; unknown names list the known ones)."""

    def __init__(self) -> None:
        self._cache: dict[tuple[str, str], type] = {}

    def known(self, kind: str) -> list[str]:
        return registry.known_names(kind)

    def load(self, kind: str, name: str) -> type:
        key = (kind, name)
        if key not in self._cache:
            self._cache[key] = registry.load_plugin(kind, name)
        return self._cache[key]


class MappingFactory:
    """Plugins from an explicit ``{kind: {name: class}}`` mapping (tests, embedding)."""

    def __init__(self, plugins: Mapping[str, Mapping[str, type]]) -> None:
        self.plugins = {k: dict(v) for k, v in plugins.items()}

    def known(self, kind: str) -> list[str]:
        return sorted(self.plugins.get(kind, {}))

    def load(self, kind: str, name: str) -> type:
        try:
            return self.plugins[kind][name]
        except KeyError:
            raise PluginError(
                f"no {kind} plugin named {name!r}; known {kind}s: {', '.join(self.known(kind)) or 'none'}"
            ) from None
