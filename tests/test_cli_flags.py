"""Scripting: a short flag means one thing across every command (walks the typer app)."""

from __future__ import annotations

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
