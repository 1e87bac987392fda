"""The package layers of studyctl import one way: down, never up, and no package-level cycle.

Every ``import`` in studyctl's source counts, at module level and inside functions alike (an import moved into a
function to dodge a cycle is still an arrow between the two packages), including ``TYPE_CHECKING`` blocks.

The layer order, lowest first. A package may import its own modules and any package of a lower layer; packages
that share a layer are siblings and import neither each other nor anything above. A new package must be placed
here before it can be imported by anything.
"""

from __future__ import annotations

import ast
import functools
from collections import defaultdict
from pathlib import Path

import pytest

import studyctl

LAYERS: tuple[tuple[str, ...], ...] = (
    ("studyctl",),  # the package's __init__: its version only
    ("errors",),  # the one exception tree
    ("suggest", "resources", "inputs", "problems", "closing"),  # did-you-mean; shipped files; bounded reading;
    # file:line problems; `with` closes a handle
    ("yamlmarks",),  # YAML with positions and size limits (protocols, plans, populations, stiffness manifests)
    ("stats", "models"),  # pure statistics; pure numerical models (arrays in, frozen results out)
    ("plugins",),  # the Controller/Device/Scene/Participant interfaces, parameters, safety, discovery
    ("protocol",),  # the protocol language, counterbalancing, schedules
    ("scenes", "controllers", "participants"),  # the built-in plugins
    ("devices",),  # simulated and hardware devices (a simulated device touches its scene)
    ("store",),  # the study database; enrollment writes a protocol's schedule into it
    ("engine",),  # sessions, trial loop, servo process, recorders
    ("view", "analysis"),  # the participant's browser view; metrics and plan execution
    ("populations",),  # virtual populations and published targets (targets name metrics of analysis plans)
    ("power", "calibration"),  # replicate studies and their power table; simulated against published numbers
    ("report",),  # tables, figures, pages: the only formatting and the only matplotlib
    ("workflows",),  # simulate, report, power run, demo: the one place that composes the layers above
    ("bench",),  # benchmarks of all of the above
    ("cli",),  # thin typer commands
    ("__main__",),  # python -m studyctl
)

ROOT = Path(studyctl.__file__).resolve().parent


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    # studyctl/_resources exists only in a built wheel (CI installs one): setup.py maps the top-level migrations/,
    # protocols/ and analysis/ folders there. Alembic's scripts are the store's data, not a layer of the package.
    return {_module_name(p): p for p in sorted(ROOT.rglob("*.py")) if "_resources" not in p.relative_to(ROOT).parts}


def _package(module: str) -> str:
    """The top-level part a module belongs to: ``studyctl.analysis.plan`` -> ``analysis``, ``studyctl`` itself ->
    ``studyctl``, a top-level module ``studyctl.errors`` -> ``errors``."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else parts[0]


def _imports(module: str, path: Path, known: set[str]) -> list[tuple[str, int]]:
    """(imported studyctl module, line) for every import statement of one file, wherever it stands."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    here = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
    found: list[tuple[str, int]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(alias.name, node.lineno) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = here[: len(here) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            # `from studyctl import bench` imports the module studyctl.bench, not the package's __init__ only
            subs = [f"{target}.{alias.name}" for alias in node.names if f"{target}.{alias.name}" in known]
            found += [(sub, node.lineno) for sub in subs] or [(target, node.lineno)]
    return sorted(((n, line) for n, line in found if n == "studyctl" or n.startswith("studyctl.")), key=lambda e: e[1])


@functools.cache  # four checks read the same graph: parse the package (~1.5 s CPU) once per test process
def _edges() -> tuple[tuple[str, str, int], ...]:
    """(importing module, imported module, line) over the whole package."""
    modules = _modules()
    known = set(modules)
    return tuple((m, target, line) for m, path in modules.items() for target, line in _imports(m, path, known))


def _rank() -> dict[str, int]:
    return {package: i for i, layer in enumerate(LAYERS) for package in layer}


def test_every_package_has_a_layer() -> None:
    rank = _rank()
    missing = sorted({_package(m) for m in _modules()} - set(rank))
    assert not missing, f"place these packages in LAYERS of {Path(__file__).name}: {missing}"


def test_no_import_goes_up_or_sideways() -> None:
    rank = _rank()
    bad = []
    for source, target, line in _edges():
        a, b = _package(source), _package(target)
        if a == b or a not in rank or b not in rank:
            continue
        if rank[b] >= rank[a]:
            way = "up" if rank[b] > rank[a] else "sideways"
            bad.append(f"{source} line {line} imports {target} ({a} -> {b}: {way})")
    assert not bad, "imports against the layer order:\n" + "\n".join(sorted(bad))


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one node (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for nxt in sorted(graph.get(node, ())):
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in on_stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            component = []
            while True:
                top = stack.pop()
                on_stack.discard(top)
                component.append(top)
                if top == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def test_no_package_level_cycle() -> None:
    graph: dict[str, set[str]] = defaultdict(set)
    for source, target, _ in _edges():
        if _package(source) != _package(target):
            graph[_package(source)].add(_package(target))
    assert not _cycles(graph)


def test_the_walker_sees_function_level_and_relative_imports(tmp_path: Path) -> None:
    """The checks above can fail: an import hidden in a function or written relatively is an arrow too."""
    source = tmp_path / "mod.py"
    source.write_text(
        "import os\nfrom . import sibling\n\ndef f():\n    from studyctl.workflows.demo import run_demo\n"
        "    import studyctl.report.figures as F\n",
        encoding="utf-8",
    )
    known = {"studyctl.engine.sibling"}
    got = _imports("studyctl.engine.mod", source, known)
    assert got == [("studyctl.engine.sibling", 2), ("studyctl.workflows.demo", 5), ("studyctl.report.figures", 6)]
    rank = _rank()
    assert rank[_package("studyctl.workflows.demo")] > rank[_package("studyctl.engine.mod")]
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


FOUNDATION = {"errors", "suggest", "resources", "inputs", "problems", "yamlmarks"}


@pytest.mark.parametrize("package", ["stats", "models"])
def test_statistics_and_models_import_only_the_foundation(package: str) -> None:
    """Statistics and numerical models take arrays and return results: nothing of studyctl but the error tree and
    the bounded readers (a stiffness map's manifest is a file)."""
    used = {_package(t) for s, t, _ in _edges() if _package(s) == package} - {package}
    assert used <= FOUNDATION, used


@pytest.mark.slow
def test_collection_imports_leave_scipy_stats_out():
    """scipy.stats (also pulled in by scipy.signal) costs about a second to import, scipy.optimize and
    scipy.interpolate together about 0.25 s CPU: the modules the test files import at collection load them only
    when a test statistic, filter, spline or root is computed."""
    import subprocess
    import sys

    code = ("import sys\n"
            "import studyctl.analysis.execute, studyctl.stats, studyctl.models.capr, studyctl.participants.palpator\n"
            "import studyctl.cli.app, studyctl.workflows.report, studyctl.stats.model_intervals\n"
            "import studyctl.workflows.calibrate\n"
            "print(sorted(m for m in ('scipy.stats', 'scipy.signal', 'scipy.optimize', 'scipy.interpolate')\n"
            "             if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout


@pytest.mark.slow
def test_collecting_the_compiled_capr_tests_leaves_numba_out():
    """numba costs about 0.25 s CPU to import; the compiled-tick tests ask whether it is installed without importing
    it, so collecting the suite does not pay for it (the tests import it when they run)."""
    import subprocess
    import sys

    repo = Path(__file__).resolve().parents[2]
    code = ("import contextlib, io, sys\n"
            "import pytest\n"
            "with contextlib.redirect_stdout(io.StringIO()):\n"
            "    code = pytest.main(['--collect-only', '-q', '-p', 'no:cacheprovider', '-m', '',\n"
            "                        'tests/palpation/test_capr_compiled.py'])\n"
            "print(int(code), 'numba' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=repo)
    assert out.stdout.split() == ["0", "False"], out.stdout + out.stderr


def test_the_exception_tree_is_imported_at_module_level_below_the_cli() -> None:
    """studyctl.errors imports nothing of studyctl, so an import of it inside a function dodges no cycle and saves
    no time (every layer has loaded it by then); it only hides from the top of the file what the module raises.
    The CLI alone imports lazily on purpose (a refused input is answered before the library loads)."""
    hidden = []
    for module, path in _modules().items():
        if _package(module) in ("cli", "__main__"):
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        for fn in ast.walk(tree):
            if isinstance(fn, ast.FunctionDef | ast.AsyncFunctionDef):
                hidden += [f"{module} line {node.lineno}" for node in ast.walk(fn)
                           if isinstance(node, ast.ImportFrom) and node.module == "studyctl.errors"]
    assert not hidden, "import studyctl.errors at the top of the file:\n" + "\n".join(sorted(set(hidden)))
