"""The stored study has one reader: no module outside ``studyctl/store`` builds SQL against the study's tables.

Analysis, figures, calibration, study progress and the data-gap count read participants, sessions, trials, events,
samples and answers through :class:`studyctl.store.reader.StudyReader` (typed rows, rehearsals left out in one
place). SQL is written with SQLAlchemy, so a module outside the store that imports ``sqlalchemy`` is building its own
query (or reaching into the database engine); each such module that is left is listed below with its reason, and an
entry that no longer imports it must be struck, so the list only shrinks.
"""

from __future__ import annotations

import ast
import functools
from collections.abc import Mapping
from pathlib import Path
from types import MappingProxyType

import studyctl

ROOT = Path(studyctl.__file__).resolve().parent

#: Modules outside the store that still import SQLAlchemy, and why.
ALLOWED = {
    "engine/store_recorder.py": "the write side: a session's recorder reads its own session's rows inside the write "
    "transaction that starts or resumes it (a participant takes part once)",
    "engine/api.py": "the write side: a running session reads its own plan and population events back",
    "engine/export.py": "the raw export of every stored row and column of a study (not yet read through the reader)",
    "engine/device_check.py": "device calibration rows, which belong to a device, not to a study's data",
    "view/board.py": "the coordinator board's audit-log feed and the study's name (not yet read through the reader)",
    "workflows/simulate.py": "a connection pragma (SQLite synchronous=NORMAL) for simulated cohorts: no query",
    "bench/store.py": "the store benchmark measures PostgreSQL's table size: no study rows",
}


def _imports_sqlalchemy(path: Path) -> list[int]:
    """Lines of ``path`` that import sqlalchemy (module level, in functions or under TYPE_CHECKING alike)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    lines = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import) and any(a.name.split(".")[0] == "sqlalchemy" for a in node.names):
            lines.append(node.lineno)
        elif isinstance(node, ast.ImportFrom) and not node.level and (node.module or "").split(".")[0] == "sqlalchemy":
            lines.append(node.lineno)
    return sorted(lines)


@functools.cache  # three checks read the same scan: parse the package (~1.5 s CPU) once per test process
def _outside_store() -> Mapping[str, tuple[int, ...]]:
    found = {}
    for path in sorted(ROOT.rglob("*.py")):
        rel = path.relative_to(ROOT)
        if rel.parts[0] in ("store", "_resources"):
            continue
        lines = _imports_sqlalchemy(path)
        if lines:
            found[rel.as_posix()] = tuple(lines)
    return MappingProxyType(found)


def test_no_sql_outside_the_store_but_the_listed_modules() -> None:
    found = _outside_store()
    new = {f: lines for f, lines in found.items() if f not in ALLOWED}
    assert not new, ("these modules query the database themselves; read a stored study through "
                     f"studyctl.store.reader.StudyReader (or add a method there): {new}")


def test_the_list_of_exceptions_only_shrinks() -> None:
    stale = sorted(set(ALLOWED) - set(_outside_store()))
    assert not stale, f"no longer import sqlalchemy: strike them from ALLOWED: {stale}"


def test_the_readers_of_stored_studies_hold_no_sql() -> None:
    """Those the issue names: progress, the data-gap count, analysis, figures, calibration and the report."""
    found = _outside_store()
    readers = [f for f in found if f.startswith(("analysis/", "report/", "calibration/", "populations/", "power/"))
               or f in ("engine/progress.py", "engine/data_gaps.py")]
    assert not readers, readers


def test_the_check_sees_every_kind_of_import(tmp_path: Path) -> None:
    """The checks above can fail: a plain, dotted, from- or function-level import of sqlalchemy is found."""
    source = tmp_path / "mod.py"
    source.write_text("import os\nimport sqlalchemy.orm\n\ndef f():\n    from sqlalchemy import func, select\n"
                      "    return select\nfrom . import sqlalchemy_like\n", encoding="utf-8")
    assert _imports_sqlalchemy(source) == [2, 5]
