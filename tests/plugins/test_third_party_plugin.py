"""A third-party plugin package, installed into a fresh virtual environment, runs a trial like a built-in.

The fresh venv sees the dev environment's packages (studyctl itself, numpy …) through a ``.pth`` file, so
nothing is downloaded; the plugin package is built and installed there by pip with its own pyproject and
entry points, and is invisible to the dev environment.
"""

from __future__ import annotations

import json
import site
import subprocess
import sys
import textwrap
import venv
from pathlib import Path

import pytest

from studyctl.errors import PluginError
from studyctl.plugins.registry import load_plugin

pytestmark = pytest.mark.slow  # spawns processes / runs whole sessions: CI runs it, plain pytest skips it

PYPROJECT = """\
[build-system]
requires = ["setuptools>=61"]
build-backend = "setuptools.build_meta"

[project]
name = "studyctl-gainplug"
version = "0.3.1"
requires-python = ">=3.11"

[project.entry-points."studyctl.controllers"]
half_linear = "gainplug:HalfLinear"
broken_one = "gainplug_broken:Nope"

[tool.setuptools]
py-modules = ["gainplug", "gainplug_broken"]
"""

PLUGIN = '''\
"""A third-party palpation controller: balloon at half the linear map, no vibration."""
from studyctl.plugins.interfaces import Controller


class HalfLinear(Controller):
    """Half of eq. 1 on the balloon only."""

    name = "half_linear"
    outputs = ("balloon_pct", "vibration_pct")

    def reset(self):
        self.calls = 0

    def step(self, obs):
        self.calls += 1
        f = obs.values["force_n"]
        return {"balloon_pct": 0.5 * 99.0 * min(max(f / 2.0, 0.0), 1.0), "vibration_pct": 0.0}
'''

BROKEN = 'raise ImportError("gainplug_broken needs libfoo, which is not installed")\n'

RUN = '''\
import json, numpy as np
from studyctl.engine.clock import SimulatedClock
from studyctl.engine.trial_loop import run_trial
from studyctl.plugins.interfaces import TrialInfo
from studyctl.plugins.registry import load_plugin

scene = load_plugin("scene", "sponge_phantom").build(
    {}, {"sites": {"soft": 1, "medium": 3, "hard": 5}}, frozenset(), np.random.default_rng(1))
controller = load_plugin("controller", "half_linear")({}, scene)
device = load_plugin("device", "sim_palpation")(params={}, scene=scene, rng=np.random.default_rng(2))
participant = load_plugin("participant", "virtual_palpator")(params={"columns": 3, "rows": 2})
device.open()
samples = []
out = run_trial(info=TrialInfo("third_party", 60.0, 50.0, public={"grid": {"columns": 3, "rows": 2, "cell_mm": 40}}),
                controller=controller, device=device, participant=participant, clock=SimulatedClock(),
                rng=np.random.default_rng(3), on_sample=lambda t, s: samples.append(s))
device.close()
print(json.dumps({"ended_by": out.ended_by, "ticks": out.ticks, "calls": controller.calls,
                  "max_balloon": max(s["balloon_pct"] for s in samples),
                  "max_vibration": max(s["vibration_pct"] for s in samples),
                  "reports": out.reports, "module": type(controller).__module__}))
'''


@pytest.fixture(scope="module")
def plugin_env(tmp_path_factory):
    root = tmp_path_factory.mktemp("thirdparty")
    pkg = root / "pkg"
    pkg.mkdir()
    (pkg / "pyproject.toml").write_text(PYPROJECT)
    (pkg / "gainplug.py").write_text(PLUGIN)
    (pkg / "gainplug_broken.py").write_text(BROKEN)
    env_dir = root / "venv"
    venv.EnvBuilder(system_site_packages=False, with_pip=False).create(env_dir)
    python = env_dir / "bin" / "python"
    purelib = subprocess.run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                             capture_output=True, text=True, check=True).stdout.strip()
    dev_site = [p for p in site.getsitepackages() if p.endswith("site-packages")][0]
    # Processed at start-up: makes the dev venv's packages (and its editable studyctl) importable.
    Path(purelib, "_dev_env.pth").write_text(f"import site; site.addsitedir({dev_site!r})\n")
    pip = subprocess.run(
        [python, "-m", "pip", "install", "--no-deps", "--no-build-isolation", "--no-index", "-q", str(pkg)],
        capture_output=True, text=True, timeout=120,
    )
    assert pip.returncode == 0, pip.stderr
    return python


def test_plugin_is_invisible_to_the_dev_environment():
    with pytest.raises(PluginError, match="no controller plugin named 'half_linear'"):
        load_plugin("controller", "half_linear")


def test_third_party_controller_runs_a_trial(plugin_env):
    out = subprocess.run([plugin_env, "-c", RUN], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert result["module"] == "gainplug"
    assert result["ended_by"] == "finish"
    assert result["calls"] == result["ticks"] > 100
    assert 0 < result["max_balloon"] <= 49.5 and result["max_vibration"] == 0.0
    assert all(1 <= r["column"] <= 3 and 1 <= r["row"] <= 2 for r in result["reports"])


def test_cli_in_the_plugin_env_lists_it_and_names_the_broken_one(plugin_env):
    out = subprocess.run([plugin_env, "-m", "studyctl", "plugins", "list", "--json", "--kind", "controller"],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    rows = {r["name"]: r for r in json.loads(out.stdout)}
    assert rows["half_linear"]["status"] == "ok"
    assert rows["half_linear"]["package"] == "studyctl-gainplug" and rows["half_linear"]["version"] == "0.3.1"
    assert rows["half_linear"]["detail"] == "Half of eq. 1 on the balloon only."
    assert rows["broken_one"]["status"] == "error"
    assert rows["broken_one"]["package"] == "studyctl-gainplug"
    assert "ImportError: gainplug_broken needs libfoo" in rows["broken_one"]["detail"]
    assert rows["linear"]["status"] == "ok" and rows["bio_inspired"]["status"] == "ok"
    strict = subprocess.run([plugin_env, "-m", "studyctl", "plugins", "list", "--kind", "controller", "--strict"],
                            capture_output=True, text=True, timeout=120)
    assert strict.returncode != 0
    assert strict.stderr.strip().splitlines()[-1].startswith("Error: 1 plugin(s) failed to load: controller broken_one")
    load = subprocess.run([plugin_env, "-c", textwrap.dedent("""
        from studyctl.plugins.registry import load_plugin
        from studyctl.errors import PluginError
        try:
            load_plugin("controller", "broken_one")
        except PluginError as exc:
            print(exc)
    """)], capture_output=True, text=True, timeout=60)
    assert "from package studyctl-gainplug 0.3.1" in load.stdout and "needs libfoo" in load.stdout
    assert sys.executable != str(plugin_env)
