"""Every installed device plugin keeps the device contract (engine.device_contract), hardware on its emulator."""

from __future__ import annotations

import numpy as np
import pytest

from studyctl.engine.device_contract import contract_problems
from studyctl.plugins.registry import known_names, load_plugin

pytestmark = pytest.mark.slow


def _scene(name: str, placement: dict):
    def build():
        return load_plugin("scene", name).build({}, placement, frozenset({"layers", "view"}), np.random.default_rng(0))
    return build


# the scenes the built-in simulated devices are used with; third-party simulated devices get none
SCENES = {
    "sim_palpation": _scene("sponge_phantom", {"sites": {"soft": 1, "medium": 2, "hard": 3}}),
    "sim_force3d": _scene("needle_liver", {"sites": {"tumour": 1}}),
    "direct_touch": _scene("stiffness_tissue", {"sites": {}}),
}


@pytest.mark.parametrize("name", known_names("device"))
def test_device_plugin_keeps_the_contract(name):
    assert contract_problems(name, scene=SCENES.get(name)) == []


def test_the_contract_catches_a_device_that_hangs_silently(monkeypatch):
    """A board adapter that keeps reporting its last sample as fresh (the silent-board bug the safety layer relies
    on sample_t for) must fail the contract's stopped-emulator check."""
    from studyctl.devices import udp_board  # noqa: PLC0415

    real_read = udp_board.UdpDriverBoard.read

    def read_always_fresh(self, t):
        obs = real_read(self, t)
        return type(obs)(obs.t, obs.values, sample_t=t, faults=obs.faults)

    monkeypatch.setattr(udp_board.UdpDriverBoard, "read", read_always_fresh)
    problems = contract_problems("udp_driver_board", ticks=50)
    assert any("not 'fault'" in p or "no device_fault" in p for p in problems), problems
