"""Scripting: a short flag means one thing across every command (walks the typer app)."""

from __future__ import annotations

import pytest
import typer.main

from studyctl.cli.app import app


def _params(group, path=()):
    for name, cmd in getattr(group, "commands", {}).items():
        yield from _params(cmd, (*path, name))
    for p in getattr(group, "params", []):
        yield path, p


def test_each_short_flag_has_one_meaning():
    meanings: dict[str, set[str]] = {}
    where: dict[str, list[str]] = {}
    for path, p in _params(typer.main.get_command(app)):
        longs = [o for o in (*p.opts, *p.secondary_opts) if o.startswith("--")]
        for short in (o for o in (*p.opts, *p.secondary_opts) if len(o) == 2 and o.startswith("-")):
            meanings.setdefault(short, set()).add(longs[0] if longs else p.name)
            where.setdefault(short, []).append(" ".join(path))
    assert meanings, "no short flags found: the walk is broken"
    clashes = {s: sorted(m) for s, m in meanings.items() if len(m) > 1}
    assert clashes == {}, {s: (m, where[s]) for s, m in clashes.items()}
    assert meanings["-w"] == {"--workspace"}


# Commands that print results but have no --json, each with the reason; a command added without --json fails
# the walk below until it gets one or is listed here.
NO_JSON: dict[str, str] = {}


def _commands(group, path=()):
    subs = getattr(group, "commands", None)
    if subs:
        for name, cmd in subs.items():
            yield from _commands(cmd, (*path, name))
    else:
        yield " ".join(path), group


def test_every_command_has_json_but_the_listed_ones():
    commands = dict(_commands(typer.main.get_command(app)))
    assert len(commands) >= 25 and {"protocol show", "db check", "device list"} <= set(commands)  # walks groups
    missing = {name for name, cmd in commands.items() if not any("--json" in p.opts for p in cmd.params)}
    # (an exemption whose command has since gained --json is harmless; drop it from NO_JSON when seen)
    assert missing <= set(NO_JSON), f"commands without --json: {sorted(missing - set(NO_JSON))}"


@pytest.mark.slow
def test_json_output_is_one_parseable_object(tmp_path, capsys):
    import json
    from pathlib import Path

    import yaml

    from studyctl.cli.app import main

    protocol = Path(__file__).parent / "engine" / "data" / "pty_protocol.yaml"
    ws = tmp_path / "ws"
    assert main(["init", str(ws), "--protocol", str(protocol), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["study"] == "engine_pty_test"
    assert main(["enroll", "--code", "PTY-AAAAA", "-w", str(ws)]) == 0
    capsys.readouterr()
    answers = tmp_path / "a.yaml"
    answers.write_text(yaml.safe_dump({"default_likert": 3, "trials": {1: [{"t": 1.0, "request": "finish"}],
                                                                      2: [{"t": 1.0, "request": "finish"}]}}))
    assert main(["run", "-p", "PTY-AAAAA", "--input", str(answers), "--json", "-w", str(ws)]) == 0
    run = json.loads(capsys.readouterr().out)
    assert run["status"] == "completed" and run["trials_completed"] == 2 and ":" in run["audit_head"]
    assert main(["export", str(tmp_path / "out"), "--json", "--no-samples", "-w", str(ws)]) == 0
    assert json.loads(capsys.readouterr().out)["rows"]["trials.csv"] == 2
    assert main(["protocol", "check", "needle_insertion", "--json"]) == 0
    checked = json.loads(capsys.readouterr().out)
    assert checked["protocol"] == "needle_insertion (shipped)" and "ESG" in checked["conditions"]
    assert main(["audit", "verify", "--json", "-w", str(ws)]) == 0
    assert json.loads(capsys.readouterr().out)["ok"] is True
    assert main(["db", "current", "--json", "-w", str(ws)]) == 0
    state = json.loads(capsys.readouterr().out)
    assert state["revision"] == state["head"]
    assert main(["db", "upgrade", "--json", "-w", str(ws)]) == 0
    assert json.loads(capsys.readouterr().out)["changed"] is False
    assert main(["db", "check", "--json", "-w", str(ws)]) == 0
    checked = json.loads(capsys.readouterr().out)
    assert checked["ok"] is True and {"schema", "sqlite integrity"} <= {c["check"] for c in checked["checks"]}
    assert main(["protocol", "show", "needle_insertion", "--json"]) == 0
    shown = json.loads(capsys.readouterr().out)
    assert shown["study"] == "needle_insertion" and shown["sequences"]
    assert [c["id"] for c in shown["protocol"]["conditions"]] == checked_conditions(shown)
    assert main(["protocol", "schedule", "needle_insertion", "-n", "2", "--json"]) == 0
    assert len({r["participant"] for r in json.loads(capsys.readouterr().out)["rows"]}) == 2


def checked_conditions(shown):
    return [c for c in ("BL", "RT", "ES", "EG", "ESG") if c in {x["id"] for x in shown["protocol"]["conditions"]}]


def test_help_shows_no_type_after_a_flag(capsys):
    from studyctl.cli.app import main

    assert main(["withdraw", "--help"]) == 0
    out = capsys.readouterr().out
    assert "--keep-data" in out and "--json" in out and "<bool>" not in out
    assert "<str>" in out  # value options keep their type


@pytest.mark.slow  # two fresh processes (~8 s on the loaded machine)
def test_shell_completion_by_typers_mechanism(tmp_path):
    import os
    import subprocess
    import sys
    from pathlib import Path

    exe = str(Path(sys.executable).parent / "studyctl")  # the installed console script (its name keys completion)
    env = {**os.environ, "_STUDYCTL_COMPLETE": "complete_bash", "COMP_WORDS": "studyctl sta", "COMP_CWORD": "1"}
    run = subprocess.run([exe], env=env, capture_output=True, text=True, timeout=60)
    assert run.returncode == 0 and run.stdout.split() == ["status"], (run.stdout, run.stderr)
    env |= {"COMP_WORDS": "studyctl protocol show ne", "COMP_CWORD": "3"}
    run = subprocess.run([exe], env=env, capture_output=True, text=True, timeout=60)
    assert run.stdout.split() == ["needle_insertion"], (run.stdout, run.stderr)
    env = {k: v for k, v in os.environ.items() if not k.startswith(("_STUDYCTL", "COMP_"))}
    env |= {"HOME": str(tmp_path), "SHELL": "/bin/bash"}
    run = subprocess.run([exe, "--install-completion", "bash"], env=env,
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stderr
    script = tmp_path / ".bash_completions" / "studyctl.sh"
    assert "_STUDYCTL_COMPLETE=complete_bash" in script.read_text()
    assert str(script) in (tmp_path / ".bashrc").read_text()


def test_status_watch_refreshes_until_ctrl_c(tmp_path, capsys, monkeypatch):
    import time

    from studyctl.cli.app import main

    assert main(["init", str(tmp_path / "ws"), "--protocol", "needle_insertion"]) == 0
    assert main(["enroll", "-w", str(tmp_path / "ws"), "--code", "NDL-AAAAA"]) == 0
    capsys.readouterr()
    naps = []

    def sleep(seconds):
        naps.append(seconds)
        if len(naps) == 3:
            raise KeyboardInterrupt

    monkeypatch.setattr(time, "sleep", sleep)
    assert main(["status", "--watch", "--interval", "0.5", "-w", str(tmp_path / "ws")]) == 0
    out = capsys.readouterr().out
    assert naps == [0.5, 0.5, 0.5] and "study:    needle_insertion" in out and "NDL-AAAAA" in out
    assert "every 0.5 s; Ctrl-C to stop" in out
    assert out.index("(read at") < out.index("study:")  # the stamp on top: a tall view is cut at the bottom
    assert main(["status", "--watch", "--json", "-w", str(tmp_path / "ws")]) != 0
    assert capsys.readouterr().err.startswith("Error: --watch shows a live view")


def test_shipped_names_complete():
    from studyctl.cli.common import complete_shipped

    assert complete_shipped("protocols")("pseudo") == ["pseudo_haptic_palpation"]
    assert complete_shipped("analysis")("pseudo") == ["pseudo_haptic_palpation", "pseudo_haptic_palpation_published"]
    assert complete_shipped("protocols")("./my") == []  # the shell then completes file names


def test_every_parameter_taking_a_shipped_name_completes_it():
    import click

    takers = []
    for path, p in _params(typer.main.get_command(app)):
        help_text = (getattr(p, "help", None) or "").lower()
        if "shipped" in help_text and ("protocol" in help_text or "plan" in help_text) and "name" in help_text:
            takers.append((" ".join(path), p))
    assert len(takers) >= 9, [t for t, _ in takers]  # protocol check/show/schedule, init, simulate, power, calibrate …
    ctx = click.Context(typer.main.get_command(app))
    for where, p in takers:
        got = [getattr(c, "value", c) for c in p.shell_complete(ctx, "needl")]  # a protocol and a plan of that name
        assert got == ["needle_insertion"], (where, p.name, got)


@pytest.mark.slow  # one simulated person (~5 s)
def test_simulate_json_is_one_object(tmp_path, capsys):
    import json
    from pathlib import Path

    from studyctl.cli.app import main

    protocol = Path(__file__).parent / "power" / "data" / "mini_palpation.yaml"
    assert main(["simulate", str(protocol), "-n", "1", "-s", "3", "-o", str(tmp_path / "w"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)  # the progress bar and population line go to stderr
    assert out["participants"] == 1 and out["trials_completed"] == 2 and Path(out["database"]).is_file()
