"""One exception tree: every error studyctl raises on purpose is a ``StudyctlError`` (studyctl/errors.py).

A raise of a bare built-in (``raise ValueError(...)``) reaches the CLI as a traceback instead of one ``Error:`` line,
and a library caller cannot catch studyctl's errors as one family. The walk below reads every ``raise`` of the
package's source; a bare built-in passes only where Python or a library requires that very type, where the same
function catches it, or where this file names it with its reason.
"""

from __future__ import annotations

import ast
import builtins
from pathlib import Path

import studyctl
import studyctl.errors

ROOT = Path(studyctl.__file__).resolve().parent

# Exception's built-in subclasses; KeyboardInterrupt and SystemExit are passed on, never made by studyctl
BUILTIN_ERRORS = {n for n, v in vars(builtins).items() if isinstance(v, type) and issubclass(v, Exception)}

# (file below studyctl/, function, built-in): why that raise is not a StudyctlError.
ALLOWED = {
    ("inputs.py", "_no_constant", "ValueError"): "json.loads' own contract (loads_json mirrors it; callers catch it)",
    ("inputs.py", "loads_json", "ValueError"): "json.loads' own contract (loads_json mirrors it; callers catch it)",
    ("devices/board_emulator.py", "_numbers", "ValueError"): "the emulator script's parser; serve() catches it",
    ("devices/board_emulator.py", "recvfrom", "BlockingIOError"): "a non-blocking socket's contract (the emulated "
    "board stands in for one): no datagram waiting",
    ("engine/terminal.py", "_ask_either", "EOFError"): "input()'s contract: the terminal closed",
    ("participants/needle_trial.py", "need_plan", "RuntimeError"): "a plugin method called out of order: a bug, not "
    "anything a user can cause",
    ("participants/needle_operator.py", "_st", "RuntimeError"): "a plugin method called out of order: a bug, not "
    "anything a user can cause",
}

# The emulated vendor SDKs stand in for third-party packages and raise what those raise.
EMULATED_SDK = ROOT / "devices" / "emulators" / "sdk"


def _raised_name(node: ast.Raise) -> str | None:
    exc = node.exc.func if isinstance(node.exc, ast.Call) else node.exc
    return exc.id if isinstance(exc, ast.Name) else None


def _caught(name: str, handlers: list[ast.ExceptHandler]) -> bool:
    for h in handlers:
        types = h.type.elts if isinstance(h.type, ast.Tuple) else [h.type]
        if any(isinstance(t, ast.Name) and t.id == name for t in types):
            return True
    return False


def _required_by_protocol(func: ast.FunctionDef | ast.AsyncFunctionDef, name: str) -> bool:
    """Python's data model or pydantic asks for this very type here."""
    if name == "NotImplementedError":  # an abstract method
        return True
    if name == "AttributeError" and func.name == "__getattr__":
        return True
    if name == "KeyError" and func.name == "__getitem__":
        return True
    decorators = {d.func.id if isinstance(d, ast.Call) and isinstance(d.func, ast.Name) else getattr(d, "id", "")
                  for d in func.decorator_list}
    return name == "ValueError" and bool(decorators & {"field_validator", "model_validator", "validator"})


def bare_raises(path: Path) -> list[tuple[str, str, int]]:
    """(function, built-in, line) of every raise of a bare built-in error in one file that no rule above allows."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    found: list[tuple[str, str, int]] = []

    def visit(node: ast.AST, func: ast.FunctionDef | ast.AsyncFunctionDef | None, caught: tuple[str, ...]) -> None:
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            func, caught = node, ()
        if isinstance(node, ast.Raise) and node.exc is not None:
            name = _raised_name(node)
            if name in BUILTIN_ERRORS and name not in caught:
                if func is None or not _required_by_protocol(func, name):
                    found.append(("<module>" if func is None else func.name, name, node.lineno))
        if isinstance(node, ast.Try):
            inside = caught + tuple(n for n in BUILTIN_ERRORS if _caught(n, node.handlers))
            for child in node.body:
                visit(child, func, inside)
            for child in [*node.handlers, *node.orelse, *node.finalbody]:
                visit(child, func, caught)
            return
        for child in ast.iter_child_nodes(node):
            visit(child, func, caught)

    visit(tree, None, ())
    return found


def test_every_raise_is_in_the_tree() -> None:
    bad = []
    for path in sorted(ROOT.rglob("*.py")):
        if EMULATED_SDK in path.parents or "_resources" in path.relative_to(ROOT).parts:
            continue
        rel = path.relative_to(ROOT).as_posix()
        bad += [f"studyctl/{rel}:{line} {func}() raises {name}" for func, name, line in bare_raises(path)
                if (rel, func, name) not in ALLOWED]
    assert not bad, "raise a StudyctlError subclass (studyctl/errors.py) instead:\n" + "\n".join(bad)


def test_every_exception_class_is_in_the_tree() -> None:
    """A class of error defined outside errors.py must derive from one of the tree's classes."""
    names = {n for n, v in vars(studyctl.errors).items() if isinstance(v, type) and issubclass(v, BaseException)}
    bad = []
    for path in sorted(ROOT.rglob("*.py")):
        if path.name == "errors.py" and path.parent == ROOT or EMULATED_SDK in path.parents:
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if not isinstance(node, ast.ClassDef):
                continue
            bases = {b.id if isinstance(b, ast.Name) else getattr(b, "attr", "") for b in node.bases}
            if bases & BUILTIN_ERRORS and not bases & names and not node.name.startswith("_"):
                bad.append(f"{path.relative_to(ROOT.parent)}:{node.lineno} class {node.name}({', '.join(bases)})")
    assert not bad, "derive from a class of studyctl/errors.py:\n" + "\n".join(bad)


def test_the_walk_finds_a_bare_raise(tmp_path: Path) -> None:
    """The check above can fail: a bare raise is found, one caught in the same function or asked for by Python is
    not."""
    source = tmp_path / "mod.py"
    source.write_text(
        "def f(x):\n    if x:\n        raise ValueError('bad')\n"
        "def g(x):\n    try:\n        raise ValueError\n    except (TypeError, ValueError):\n        return 0\n"
        "class M:\n    def __getitem__(self, k):\n        raise KeyError(k)\n"
        "    def __getattr__(self, k):\n        raise AttributeError(k)\n"
        "def h():\n    raise RuntimeError('x') from None\n",
        encoding="utf-8",
    )
    assert bare_raises(source) == [("f", "ValueError", 3), ("h", "RuntimeError", 15)]
