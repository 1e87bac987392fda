"""Device test helpers: a study workspace with one enrolled participant."""

from __future__ import annotations

import pytest

from studyctl.store.enrollment import enroll, study_protocol
from studyctl.store.workspace import init_workspace, open_study


@pytest.fixture
def study(tmp_path):
    """``make(protocol) -> (opened study, participant code)``; closes what it opened."""
    opened = []

    def make(protocol: str, group: str | None = None):
        root = tmp_path / protocol
        init_workspace(root, protocol=protocol)
        o = open_study(workspace=root)
        opened.append(o)
        strata = [s.id for s in (study_protocol(o.study).participants.strata or [])]
        code = enroll(o.store, group or (strata[0] if strata else None), study=o.study.name).code
        return o, code

    yield make
    for o in opened:
        o.store.close()
