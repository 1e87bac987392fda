"""The virtual palpator: it acts through the device, feels only the actuators, and reports grid cells."""

from __future__ import annotations

import numpy as np
import pytest

from studyctl.controllers.palpation import LinearController, NoFeedback
from studyctl.devices.palpation import SimulatedPalpationDevice
from studyctl.engine.clock import SimulatedClock
from studyctl.engine.trial_loop import run_trial
from studyctl.errors import ModelParameterError
from studyctl.participants.palpator import VirtualPalpator
from studyctl.plugins.interfaces import TrialInfo
from studyctl.scenes.sponge import SpongePhantomScene


class SpyDevice(SimulatedPalpationDevice):
    """Records what the participant is given to feel."""

    def feedback(self):
        out = super().feedback()
        self.felt_keys = getattr(self, "felt_keys", set()) | set(out)
        return out


def trial(controller_cls, sites, seed, params=None, limit=600.0):
    scene = SpongePhantomScene.build({}, {"sites": sites}, frozenset(), np.random.default_rng(seed))
    device = SpyDevice({}, scene, np.random.default_rng(seed + 1))
    device.open()
    participant = VirtualPalpator(params or {})
    samples = []
    out = run_trial(
        info=TrialInfo(controller_cls.name, limit, 50.0, public=dict(scene.public())),
        controller=controller_cls({}, scene), device=device, participant=participant, clock=SimulatedClock(),
        rng=np.random.default_rng(seed + 2), on_sample=lambda t, s: samples.append(s),
    )
    device.close()
    return out, scene, device, samples


def found(out, scene):
    truth = scene.truth()["tumours"]
    return {t["class"]: any(max(abs(r["column"] - t["col"]), abs(r["row"] - t["row"])) <= 1 for r in out.reports)
            for t in truth}


SITES = ({"soft": 1, "medium": 3, "hard": 7}, {"soft": 5, "medium": 2, "hard": 4}, {"soft": 6, "medium": 7,
                                                                                         "hard": 1})


def test_without_feedback_reports_do_not_depend_on_the_tumours():
    a, _, dev, _ = trial(NoFeedback, SITES[0], seed=11)
    b, _, _, _ = trial(NoFeedback, SITES[1], seed=11)
    assert a.ended_by == b.ended_by == "finish"
    assert a.reports and [(r["column"], r["row"]) for r in a.reports] == [(r["column"], r["row"]) for r in b.reports]
    assert len(a.reports) == 3  # it guesses when nothing stood out
    assert all(1 <= r["column"] <= 7 and 1 <= r["row"] <= 7 for r in a.reports)
    assert dev.felt_keys == {"balloon_psi", "vibration_hz", "vibration_ms2"}  # all it is given to feel


def test_detection_emerges_from_the_feedback():
    hard = 0
    for seed, sites in enumerate(SITES):
        out, scene, _, samples = trial(LinearController, sites, seed=seed)
        assert out.ended_by == "finish"
        hard += found(out, scene)["hard"]
        # it pressed every cell of the 7 x 7 grid, then re-checked some
        assert out.duration_s > 49 * 1.5
        assert max(s["force_n"] for s in samples) > 1.5
    assert hard == 3


def test_noisier_perception_finds_less():
    precise = sum(sum(found(*trial(LinearController, s, seed=k)[:2]).values()) for k, s in enumerate(SITES))
    numb = {"balloon_weber": 1.5, "vibration_weber": 1.5, "guesses": 0}
    blunt = sum(sum(found(*trial(LinearController, s, seed=k, params=numb)[:2]).values()) for k, s in enumerate(SITES))
    assert blunt < precise


def test_reports_before_the_time_limit():
    out, _, _, _ = trial(LinearController, SITES[0], seed=3, limit=30.0)
    assert out.ended_by == "finish" and out.duration_s < 30.0
    assert out.reports  # decided from the cells it managed to feel


def test_grid_comes_from_the_trial_info():
    p = VirtualPalpator({})
    p.begin_trial(TrialInfo("x", 60, 50, public={"grid": {"columns": 3, "rows": 2, "cell_mm": 40}}),
                  np.random.default_rng(0))
    assert (p.columns, p.rows, p.cell_mm) == (3, 2, 40.0)
    p.begin_trial(TrialInfo("x", 60, 50, public={"report": {"columns": ["1", "2"], "rows": ["1", "2", "3"]}}),
                  np.random.default_rng(0))
    assert (p.columns, p.rows, p.cell_mm) == (2, 3, 20.0)
    with pytest.raises(ModelParameterError, match="the trial's grid .* is incomplete"):
        p.begin_trial(TrialInfo("x", 60, 50, public={"grid": {"columns": 3}}), np.random.default_rng(0))


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({"checkpoints": [0.5, 0.3]}, "checkpoints [0.5, 0.3] must be increasing fractions in (0, 1]"),
        ({"depth_mm": 0}, "parameter 'depth_mm' = 0 is out of range"),
        ({"balloon_weber": 0}, "parameter 'balloon_weber' = 0 is out of range"),
    ],
)
def test_bad_parameters(params, message):
    with pytest.raises(ModelParameterError) as err:
        VirtualPalpator(params)
    assert message in str(err.value)
