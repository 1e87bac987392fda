"""Plugin discovery: known names, unknown names, broken packages, conflicts, the CLI listing."""

from __future__ import annotations

import json
from importlib.metadata import EntryPoint

import pytest

from studyctl.cli.app import main
from studyctl.errors import PluginError
from studyctl.plugins import registry
from studyctl.plugins.interfaces import Controller, Device, Participant, Scene

PALPATION = {
    "controller": ["none", "linear", "piecewise", "bio_inspired"],
    "device": ["sim_palpation", "udp_driver_board"],
    "scene": ["sponge_phantom"],
    "participant": ["virtual_palpator"],
}


@pytest.mark.parametrize(("kind", "name"), [(k, n) for k, names in PALPATION.items() for n in names])
def test_builtin_palpation_plugins_load_through_entry_points(kind, name):
    cls = registry.load_plugin(kind, name)
    assert issubclass(cls, registry.BASES[kind])
    assert cls.name == name


def test_kind_accepts_plural_and_rejects_unknown():
    assert registry.normalise_kind("Controllers") == "controller"
    with pytest.raises(PluginError, match="unknown plugin kind 'widget'; kinds: controller, device, scene"):
        registry.load_plugin("widget", "x")


def test_unknown_name_lists_the_known_ones():
    with pytest.raises(PluginError) as err:
        registry.load_plugin("controller", "bio_inspried")
    msg = str(err.value)
    assert msg.startswith("no controller plugin named 'bio_inspried'; known controllers: ")
    for name in PALPATION["controller"]:
        assert name in msg


class _Dist:
    """Just enough of importlib.metadata.Distribution for the registry's messages."""

    def __init__(self, name, version="9.9"):
        self.name, self.version, self.metadata = name, version, {"Name": name}


def _ep(name, value, group="studyctl.controllers", dist="thirdparty-pkg"):
    ep = EntryPoint(name, value, group)
    return ep._for(_Dist(dist)) if hasattr(ep, "_for") else ep


def _fake_entry_points(monkeypatch, extra):
    real = registry._entry_points

    def fake(kind):
        return sorted(real(kind) + [e for e in extra if e.group == registry.GROUPS[kind]],
                      key=lambda e: (e.name, e.value))

    monkeypatch.setattr(registry, "_entry_points", fake)


def test_broken_plugin_names_package_and_error_and_others_still_list(monkeypatch):
    _fake_entry_points(monkeypatch, [
        _ep("broken", "studyctl_no_such_module_xyz:Thing"),
        _ep("not_a_controller", "collections:OrderedDict"),
    ])
    with pytest.raises(PluginError) as err:
        registry.load_plugin("controller", "broken")
    msg = str(err.value)
    assert "controller plugin 'broken' from package thirdparty-pkg 9.9" in msg
    assert "failed to import: ModuleNotFoundError: No module named 'studyctl_no_such_module_xyz'" in msg
    with pytest.raises(PluginError, match="is not a subclass of studyctl.plugins.interfaces.Controller"):
        registry.load_plugin("controller", "not_a_controller")

    listing = registry.list_plugins("controller")
    status = {p.name: p for p in listing.plugins}
    assert status["broken"].status == "error" and "ModuleNotFoundError" in status["broken"].detail
    assert status["broken"].package == "thirdparty-pkg"
    assert status["not_a_controller"].status == "error"
    for name in PALPATION["controller"]:
        assert status[name].status == "ok", status[name]
    frame = listing.to_frame()
    assert list(frame.columns) == list(registry.COLUMNS)
    assert {p.name for p in listing.broken} >= {"broken", "not_a_controller"}


def test_same_name_from_two_packages_is_a_conflict(monkeypatch):
    _fake_entry_points(monkeypatch, [_ep("linear", "somewhere_else:Linear", dist="other-pkg")])
    with pytest.raises(PluginError, match="registered by more than one package: .*other-pkg"):
        registry.load_plugin("controller", "linear")
    rows = [p for p in registry.list_plugins("controller").plugins if p.name == "linear"]
    assert {r.status for r in rows} == {"conflict"}


def test_cli_lists_plugins_as_json_and_table(capsys):
    assert main(["plugins", "list", "--json", "--kind", "scene"]) == 0
    rows = json.loads(capsys.readouterr().out)
    sponge = next(r for r in rows if r["name"] == "sponge_phantom")
    assert sponge["status"] == "ok" and sponge["package"] == "studyctl" and sponge["kind"] == "scene"
    assert main(["plugins", "list", "--kind", "participant"]) == 0
    assert "virtual_palpator" in capsys.readouterr().out


def test_cli_unknown_kind_is_one_line_error(capsys):
    code = main(["plugins", "list", "--kind", "gadgets"])
    err = capsys.readouterr().err
    assert code != 0 and err.startswith("Error: unknown plugin kind 'gadgets'") and "Traceback" not in err


def test_cli_strict_fails_when_a_plugin_is_broken(monkeypatch, capsys):
    _fake_entry_points(monkeypatch, [_ep("broken", "studyctl_no_such_module_xyz:Thing")])
    assert main(["plugins", "list", "--kind", "controller"]) == 0  # listing still works
    out = capsys.readouterr().out
    assert "broken" in out and "linear" in out
    code = main(["plugins", "list", "--kind", "controller", "--strict"])
    assert code != 0
    assert "failed to load: controller broken" in capsys.readouterr().err


def test_interfaces_keep_working_for_minimal_plugins():
    """Older plugins that define only the abstract methods still construct (additions have defaults)."""

    class MinimalDevice(Device):
        name = "minimal"

        def open(self): ...
        def read(self, t): ...
        def write(self, command): ...
        def close(self): ...

    class MinimalParticipant(Participant):
        name = "p"

        def begin_trial(self, info, rng): ...
        def act(self, t, percept): ...

    class MinimalScene(Scene):
        name = "s"

        @classmethod
        def build(cls, spec, placement, needs, rng):
            return cls()

        def sense(self, inputs):
            return {}

    dev = MinimalDevice(params={"a": 1})
    assert dev.params == {"a": 1} and dev.scene is None and MinimalDevice().params == {}
    assert MinimalParticipant().params == {}
    assert MinimalScene.build({}, {}, frozenset(), None).public() == {}
    assert Controller.outputs == ()


def test_the_installed_plugins_are_scanned_once_until_a_package_is_installed(tmp_path, monkeypatch):
    import time

    monkeypatch.syspath_prepend(str(tmp_path))
    scans = []
    real = registry.entry_points

    def counting(**kw):
        scans.append(kw["group"])
        return real(**kw)

    monkeypatch.setattr(registry, "entry_points", counting)
    assert "late_scene" not in registry.known_names("scene")
    registry.load_plugin("scene", "sponge_phantom")
    registry.known_names("scene")
    assert scans == ["studyctl.scenes"]  # one scan for the three lookups

    time.sleep(0.05)  # past the file system's time stamp granularity, as any real install is
    (tmp_path / "late_scene_plugin.py").write_text(
        "from studyctl.plugins.interfaces import Scene\n\nclass LateScene(Scene):\n    '''Installed late.'''\n")
    dist = tmp_path / "late_scene_plugin-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: late-scene-plugin\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text("[studyctl.scenes]\nlate_scene = late_scene_plugin:LateScene\n")
    assert "late_scene" in registry.known_names("scene")  # the new distribution is seen
    assert registry.load_plugin("scene", "late_scene").__name__ == "LateScene"
    assert scans == ["studyctl.scenes", "studyctl.scenes"]
