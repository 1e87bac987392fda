"""Seeded virtual sessions, pinned to the bit: what a speed-up of the per-tick code must leave unchanged.

Two small seeded studies run through ``simulate_study`` (the path of ``studyctl simulate``, ``studyctl power``
and the demo): bio-inspired palpation (seed 000: CAPR controller, palpation hardware, sponge scene) with two
people, and pseudo-haptic palpation (seed 003: tissue controllers, 3-D force device, tissue scene) with one
person at the demo's 250 Hz loop. Every trial row, event payload and sample stream they store is hashed and
compared with ``pinned_sessions.json``. Sample chunks are hashed per stream as wholes: where chunk boundaries
fall follows wall time.

Trials and the number of sample streams are pinned for every machine; events and samples per platform
(``tests/platform_pins.py``: numpy's CPU dispatch and the numeric libraries' versions decide a force trace's last
bits). On a platform with no pin yet only the portable parts are compared, with a warning naming the platform.

If the simulated sessions were meant to change (a participant's behaviour, a scene's or controller's numbers,
a population), re-pin with ``STUDYCTL_REPIN=1 pytest tests/engine/test_pinned_sessions.py -m ''`` and say why
in the commit. A change that is only meant to be faster must pass without re-pinning.
"""

from __future__ import annotations

import hashlib
import json
import os
import sqlite3
from pathlib import Path

import pytest
from platform_pins import no_pin_here, platform_description, platform_key

from studyctl.workflows.simulate import simulate_study

pytestmark = pytest.mark.slow  # whole virtual sessions (run by CI with -m '')

PINNED = Path(__file__).parent / "pinned_sessions.json"
# name: (protocol, participants, master seed, loop rate cap in Hz or None for the protocol's own)
CASES = {
    "seed000": ("bio_inspired_palpation", 2, 7, None),
    "seed003_250hz": ("pseudo_haptic_palpation", 1, 7, 250.0),
}


def _sha(value: object) -> str:
    return hashlib.sha256(repr(value).encode()).hexdigest()


def _portable(kind: str, payload: str) -> str:
    """An event's payload without what names this checkout (the population file's path)."""
    if kind != "population":
        return payload
    body = json.loads(payload)
    body.pop("file", None)
    return json.dumps(body, sort_keys=True)


def session_digest(database: Path) -> dict[str, str]:
    """sha256 of the stored trials, events (without the process records, which name the machine, and the
    population file's path) and of every sample stream's times and values."""
    con = sqlite3.connect(database)
    try:
        trials = list(con.execute("select plan_position, condition, status, outcome from trial order by id"))
        events = [(trial, kind, _portable(kind, payload)) for trial, kind, payload in con.execute(
            "select trial_id, kind, payload from event where kind != 'session_process' order by id")]
        streams: dict[tuple, list] = {}
        for row in con.execute("select trial_id, stream, channels, dtype, t, data from sample_chunk "
                               "order by trial_id, stream, chunk_index"):
            h = streams.setdefault(row[:4], [hashlib.sha256(), hashlib.sha256()])
            h[0].update(row[4])
            h[1].update(row[5])
    finally:
        con.close()
    assert trials and events and streams, "the seeded study stored no trials, events or samples"
    return {
        "trials": _sha(trials),
        "events": _sha(events),
        "samples": _sha({k: (a.hexdigest(), b.hexdigest()) for k, (a, b) in streams.items()}),
        "streams": str(len(streams)),
    }


PORTABLE = ("trials", "streams")  # the same on every machine; events and samples carry force traces' last bits


@pytest.mark.parametrize("case", sorted(CASES))
def test_seeded_sessions_are_pinned(case: str, tmp_path: Path) -> None:
    protocol, people, seed, rate = CASES[case]
    simulate_study(protocol, people, seed, tmp_path / "ws", sim_rate_hz=rate)
    got = session_digest(tmp_path / "ws" / "study.db")
    pinned = json.loads(PINNED.read_text()) if PINNED.exists() else {}
    key = platform_key()
    if os.environ.get("STUDYCTL_REPIN") == "1":
        entry = pinned.setdefault(case, {})
        entry.update({k: got[k] for k in PORTABLE})
        entry.setdefault("platforms", {})[key] = {"platform": platform_description(),
                                   **{k: v for k, v in got.items() if k not in PORTABLE}}
        PINNED.write_text(json.dumps(pinned, indent=1, sort_keys=True) + "\n")
    entry = pinned.get(case, {})
    here = entry.get("platforms", {}).get(key)
    if here is None:
        no_pin_here(f"{case} events and samples", "tests/engine/pinned_sessions.json")
    want = {k: entry.get(k) for k in PORTABLE}
    want.update({k: v for k, v in (here or {}).items() if k != "platform"})
    changed = [k for k, v in want.items() if got.get(k) != v]
    assert not changed, (
        f"{case}: the stored {', '.join(changed)} differ from tests/engine/pinned_sessions.json (platform {key}); if "
        "the simulated sessions were meant to change, re-pin with STUDYCTL_REPIN=1 (see this file's docstring)"
    )
