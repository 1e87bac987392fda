"""Fixtures of the protocol tests: a small valid protocol to mutate, and a writer for protocol files."""

from __future__ import annotations

import textwrap

import pytest

VALID = """\
studyctl_protocol: 1
study:
  id: mini
  title: Minimal study
  version: "1"
  seed: 7
devices:
  simulated: {plugin: sim_palpation}
participants:
  strata:
    - {id: novice, target_n: 4}
    - {id: expert, target_n: 4}
conditions:
  - {id: A, controller: none}
  - {id: B, controller: linear}
  - {id: C, controller: piecewise}
  - {id: D, controller: bio_inspired}
counterbalance:
  scheme: williams
trial:
  time_limit_s: 60
  break_s: 30
  report: {kind: grid_cell, grid: {columns: 7, rows: 7}, hit_radius: 1}
scene:
  plugin: sponge_phantom
  placement: {sites: 7, items: [soft, medium, hard], differ_from_previous: every_item}
instruments:
  - id: likert
    version: "1"
    scale: {points: 5, anchors: {1: Strongly disagree, 5: Strongly agree}}
    items:
      - {id: easy, text: It was easy.}
questionnaires:
  - {instrument: likert, when: after_condition}
"""


@pytest.fixture
def write(tmp_path):
    """Write protocol text (dedented) to ``tmp_path/name`` and return the path as a string."""

    def _write(text: str, name: str = "p.yaml") -> str:
        path = tmp_path / name
        path.write_text(textwrap.dedent(text), encoding="utf-8")
        return str(path)

    return _write


@pytest.fixture
def valid_text() -> str:
    return VALID
