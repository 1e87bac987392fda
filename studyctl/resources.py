"""Locate the data that ships with studyctl: reference protocols, analysis plans, migrations.

In a source checkout they live in the top-level ``protocols/``, ``analysis/`` and ``migrations/``
folders; in an installed wheel they are the ``studyctl._resources`` packages (see ``setup.py``).
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from studyctl.errors import NotFoundError

_KINDS = ("protocols", "analysis", "migrations")


def resource_dir(kind: str) -> Path:
    """Return the folder holding the shipped resources of ``kind`` (protocols, analysis, migrations)."""
    if kind not in _KINDS:
        raise NotFoundError(f"unknown resource kind {kind!r}; expected one of {', '.join(_KINDS)}")
    try:
        root = resources.files(f"studyctl._resources.{kind}")
        path = Path(str(root))
        if path.is_dir():
            return path
    except ModuleNotFoundError:
        pass
    source_tree = Path(__file__).resolve().parent.parent / kind
    if source_tree.is_dir():
        return source_tree
    raise NotFoundError(f"studyctl's {kind} folder is missing from this installation; reinstall studyctl")


def shipped_names(kind: str, suffix: str = ".yaml") -> list[str]:
    """Names (file stems) of the shipped protocols or analysis plans."""
    return sorted(p.stem for p in resource_dir(kind).glob(f"*{suffix}"))


def find_shipped(kind: str, name_or_path: str | Path) -> Path:
    """Resolve a file path, or the name of a shipped protocol/plan, to an existing path."""
    candidate = Path(name_or_path)
    if candidate.is_file():
        return candidate
    shipped = resource_dir(kind) / f"{name_or_path}.yaml"
    if shipped.is_file():
        return shipped
    what = "protocol" if kind == "protocols" else "analysis plan" if kind == "analysis" else kind
    if candidate.is_dir():
        raise NotFoundError(f"{str(name_or_path)!r} is a folder, not a file; give the {what}'s YAML file "
                            f"(e.g. {candidate / 'my_study.yaml'}) or a shipped {what} name")
    if candidate.exists():
        raise NotFoundError(f"{str(name_or_path)!r} is not a regular file (a device, pipe or socket); give the "
                            f"{what}'s YAML file or a shipped {what} name")
    names = ", ".join(shipped_names(kind)) or "none"
    raise NotFoundError(
        f"no file {str(name_or_path)!r} and no shipped {kind[:-1] if kind != 'analysis' else 'analysis plan'}"
        f" of that name; shipped: {names}"
    )


def shipped_plan_for(protocol_path: str | Path) -> Path | None:
    """The shipped analysis plan of a shipped protocol file (the plan of the same name), or None.

    Only a protocol that is itself shipped gets a default plan: a user's own protocol file may share a
    name with a shipped one and still measure different things.
    """
    path = Path(protocol_path)
    try:
        shipped = path.resolve().parent == resource_dir("protocols").resolve()
    except OSError:
        return None
    plan = resource_dir("analysis") / f"{path.stem}.yaml"
    return plan if shipped and plan.is_file() else None
