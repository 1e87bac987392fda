"""The one rule for a stored trial's ground truth (tumour sites, nodule centres, the planned needle path).

The truth is the scene as it was built for the trial: the ``scene_truth`` event when the engine recorded
one (:attr:`studyctl.store.reader.TrialRow.stored_truth`), otherwise the scene plugin rebuilt from the
stored session plan (scene spec, the trial's placement and the seeded scene stream of its plan step),
which is what databases written before truth events were stored need.

The rule lives here, above the store and not in :mod:`studyctl.store.reader`, because the rebuild needs
the engine's seeding (:func:`studyctl.engine.seeding.trial_streams`) and the scene plugins, which the store
must not import (the store sits below the engine).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from studyctl.errors import AnalysisError

if TYPE_CHECKING:
    from studyctl.engine.plan import SessionPlan
    from studyctl.plugins.interfaces import Scene
    from studyctl.store.reader import TrialRow


class SceneTruth:
    """Ground truth of stored trials; owns the scene classes it looked up (entry-point lookups are slow).

    One instance per analysis run or report: nothing is cached at module level.
    """

    def __init__(self) -> None:
        self._scenes: dict[str, type[Scene]] = {}

    def of(self, trial: TrialRow, plan: SessionPlan | None, seed: int) -> Mapping[str, Any]:
        """The trial's truth: the stored one, else the scene rebuilt from ``plan`` and the session ``seed``."""
        stored = trial.stored_truth
        if stored is not None:
            return dict(stored)
        if plan is None:
            raise AnalysisError("the trial's session stored no plan, so its scene cannot be rebuilt for scoring")
        return self.rebuild(plan, trial.placement, seed, trial.step)

    def rebuild(self, plan: SessionPlan, placement: Mapping[str, Any], seed: int, position: int) -> Mapping[str, Any]:
        """The scene's ground truth, rebuilt exactly as the engine built the scene at plan step ``position``."""
        from studyctl.engine.seeding import trial_streams
        from studyctl.plugins import registry

        if not plan.scene:
            raise AnalysisError("the study's plan names no scene, so there is no ground truth to score against")
        cls = self._scenes.get(plan.scene)
        if cls is None:
            cls = self._scenes[plan.scene] = registry.load_plugin("scene", plan.scene)
        scene = cls.build(plan.scene_spec, dict(placement or {}), frozenset(), trial_streams(seed, position).scene)
        return scene.truth()
