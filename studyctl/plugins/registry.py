"""Find plugins through entry points; built-ins register exactly like third-party packages.

Four entry-point groups, one per kind::

    [project.entry-points."studyctl.controllers"]   name = "package.module:Class"
    [project.entry-points."studyctl.devices"]
    [project.entry-points."studyctl.scenes"]
    [project.entry-points."studyctl.participants"]

:func:`load_plugin` returns one class (the engine's factory calls it); an unknown name lists the known
ones, a plugin that fails to import names its package and the error. :func:`list_plugins` imports
every plugin and keeps going past broken ones, so one bad package never hides the others.
"""

from __future__ import annotations

import inspect
import os
import sys
from dataclasses import asdict, dataclass
from importlib.metadata import EntryPoint, entry_points
from typing import TYPE_CHECKING

from studyctl.errors import PluginError
from studyctl.plugins.interfaces import Controller, Device, Participant, Scene

if TYPE_CHECKING:
    import pandas as pd

GROUPS: dict[str, str] = {
    "controller": "studyctl.controllers",
    "device": "studyctl.devices",
    "scene": "studyctl.scenes",
    "participant": "studyctl.participants",
}
BASES: dict[str, type] = {"controller": Controller, "device": Device, "scene": Scene, "participant": Participant}


def normalise_kind(kind: str) -> str:
    """Accept ``controller`` or ``controllers`` (and the other kinds); raise PluginError otherwise."""
    k = kind.strip().lower()
    if k.endswith("s") and k[:-1] in GROUPS:
        k = k[:-1]
    if k not in GROUPS:
        raise PluginError(f"unknown plugin kind {kind!r}; kinds: {', '.join(GROUPS)}")
    return k


# Scanning the installed distributions for a group takes ~5 ms, and a virtual session loads its plugins ~10 times
# (~3 CPU s over the demo's 77 sessions): the scan is kept per group for as long as sys.path's entries are unchanged.
_SCANS: dict[str, tuple[tuple[tuple[str, int | None], ...], list[EntryPoint]]] = {}


def _paths_state() -> tuple[tuple[str, int | None], ...]:
    """sys.path's entries with their modification times (ns; None when missing). Installing, upgrading or removing
    a distribution adds or removes its ``.dist-info`` (or a ``.pth`` file) in one of them, which changes that
    folder's time, so an unchanged state means unchanged entry points (~20 µs to take)."""
    state = []
    for entry in sys.path:
        try:
            state.append((entry, os.stat(entry or ".").st_mtime_ns))
        except OSError:
            state.append((entry, None))
    return tuple(state)


def _entry_points(kind: str) -> list[EntryPoint]:
    group = GROUPS[kind]
    state = _paths_state()
    cached = _SCANS.get(group)
    if cached is None or cached[0] != state:
        cached = (state, sorted(entry_points(group=group), key=lambda ep: (ep.name, ep.value)))
        _SCANS[group] = cached
    return list(cached[1])


def _package(ep: EntryPoint) -> tuple[str, str]:
    dist = getattr(ep, "dist", None)
    if dist is None:
        return "?", "?"
    return dist.metadata["Name"] or dist.name, dist.version


def known_names(kind: str) -> list[str]:
    """Names registered for ``kind`` (whether or not they import)."""
    return sorted({ep.name for ep in _entry_points(normalise_kind(kind))})


class _BrokenPlugin(PluginError):
    """A plugin that is registered but unusable; ``short`` is the reason without the plugin's identity."""

    def __init__(self, message: str, short: str) -> None:
        super().__init__(message)
        self.short = short


def _import(kind: str, ep: EntryPoint) -> type:
    package, version = _package(ep)
    who = f"{kind} plugin {ep.name!r} from package {package} {version} ({ep.value})"
    try:
        obj = ep.load()
    except Exception as exc:  # any import-time failure of a plugin package is reported, never raised raw
        short = f"{type(exc).__name__}: {exc}"
        raise _BrokenPlugin(f"{who} failed to import: {short}", short) from None
    base = BASES[kind]
    if not (inspect.isclass(obj) and issubclass(obj, base)):
        short = f"not a subclass of studyctl.plugins.interfaces.{base.__name__}"
        raise _BrokenPlugin(f"{who} is {short}", short)
    return obj


def load_plugin(kind: str, name: str) -> type:
    """The plugin class registered as ``name`` for ``kind``.

    Raises
    ------
    PluginError
        Unknown kind or name (the message lists the known names), two packages registering the same
        name, an import failure (names the package and the error) or a class of the wrong base.
    """
    k = normalise_kind(kind)
    matches = [ep for ep in _entry_points(k) if ep.name == name]
    if not matches:
        known = ", ".join(known_names(k)) or "none"
        raise PluginError(f"no {k} plugin named {name!r}; known {k}s: {known}")
    if len({ep.value for ep in matches}) > 1:
        owners = "; ".join(f"{_package(ep)[0]} ({ep.value})" for ep in matches)
        raise PluginError(f"{k} plugin name {name!r} is registered by more than one package: {owners}")
    return _import(k, matches[0])


@dataclass(frozen=True)
class PluginInfo:
    """One registered plugin and whether it imports."""

    kind: str
    name: str
    target: str
    package: str
    version: str
    status: str  # "ok", "error", "conflict"
    detail: str  # first docstring line when ok, the error otherwise


COLUMNS = ("kind", "name", "target", "package", "version", "status", "detail")


@dataclass(frozen=True)
class PluginListing:
    """Every plugin found, including the broken ones."""

    plugins: tuple[PluginInfo, ...]

    def to_frame(self) -> pd.DataFrame:
        import pandas as pd  # noqa: PLC0415 - only here: the servo process loads plugins without pandas

        return pd.DataFrame([asdict(p) for p in self.plugins], columns=list(COLUMNS))

    @property
    def broken(self) -> tuple[PluginInfo, ...]:
        return tuple(p for p in self.plugins if p.status != "ok")


def _summary(cls: type) -> str:
    doc = inspect.getdoc(cls) or ""
    return doc.strip().splitlines()[0] if doc.strip() else ""


def list_plugins(kind: str | None = None) -> PluginListing:
    """Import every registered plugin (of one kind, or all) and report each one's status."""
    kinds = [normalise_kind(kind)] if kind else list(GROUPS)
    rows: list[PluginInfo] = []
    for k in kinds:
        eps = _entry_points(k)
        values_by_name: dict[str, set[str]] = {}
        for ep in eps:
            values_by_name.setdefault(ep.name, set()).add(ep.value)
        seen: set[tuple[str, str]] = set()
        for ep in eps:
            if (ep.name, ep.value) in seen:
                continue  # the same distribution seen through two paths
            seen.add((ep.name, ep.value))
            package, version = _package(ep)
            if len(values_by_name[ep.name]) > 1:
                rows.append(PluginInfo(k, ep.name, ep.value, package, version, "conflict",
                                       "name registered by more than one package"))
                continue
            try:
                cls = _import(k, ep)
            except _BrokenPlugin as exc:
                rows.append(PluginInfo(k, ep.name, ep.value, package, version, "error", exc.short))
                continue
            rows.append(PluginInfo(k, ep.name, ep.value, package, version, "ok", _summary(cls)))
    return PluginListing(tuple(rows))
