"""Cross-reference and feasibility checks on the raw protocol data.

These run on the plain YAML data (not the validated model) so that a file with type errors still gets
its reference errors reported in the same ``check``: every check tolerates missing or mistyped parts.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Iterator
from typing import Any

from studyctl.errors import StudyctlError
from studyctl.plugins.params import declared_problems
from studyctl.plugins.registry import known_names, load_plugin
from studyctl.problems import KeyPath, Problem, one_of, show
from studyctl.protocol.schema import MAX_BLOCKS, MAX_REPETITIONS, MAX_TRIALS
from studyctl.suggest import nearest
from studyctl.yamlmarks import MarkedData

MAX_ALL_PERMUTATIONS = 8  # 8! = 40,320 sequences; beyond that use williams or random


def _get(data: Any, *path: str | int) -> Any:
    node = data
    for step in path:
        if isinstance(step, int):
            if not isinstance(node, list) or not 0 <= step < len(node):
                return None
        elif not isinstance(node, dict) or step not in node:
            return None
        node = node[step]
    return node


def _items(data: Any, *path: str | int) -> Iterator[tuple[int, Any]]:
    node = _get(data, *path)
    if isinstance(node, list):
        yield from enumerate(node)


@functools.cache
def _plugin_class(kind: str, name: str) -> type | None:
    try:
        return load_plugin(kind, name)
    except StudyctlError:
        return None


def plugin_names(kind: str) -> list[str]:
    """Names registered under the entry-point group of a plugin kind (controller, device, scene, participant).

    The registry's scan (:func:`studyctl.plugins.registry.known_names`), kept until a package is installed.
    """
    return known_names(kind)


class _Checker:
    def __init__(self, marked: MarkedData, filename: str) -> None:
        self.m = marked
        self.d = marked.data
        self.file = filename
        self.problems: list[Problem] = []

    def add(self, path: KeyPath, what: str, found: str, allowed: str, suggestion: str | None = None,
            at_key: bool = False) -> None:
        mark = self.m.key_mark(path) if at_key else self.m.value_mark(path)
        self.problems.append(Problem(self.file, mark, tuple(path), what, found, allowed, suggestion))

    # -- ids ----------------------------------------------------------------------------------------
    def unique_ids(self, *list_path: str | int, kind: str) -> list[str]:
        seen: dict[str, int] = {}
        ids: list[str] = []
        for index, entry in _items(self.d, *list_path):
            ident = _get(entry, "id")
            if not isinstance(ident, str):
                continue
            if ident in seen:
                first = self.m.value_mark((*list_path, seen[ident], "id"))
                self.add((*list_path, index, "id"), f"duplicate {kind} id (first defined at line {first.line})",
                         show(ident), f"an id not used by another {kind}")
            else:
                seen[ident] = index
                ids.append(ident)
        return ids

    def reference(self, path: KeyPath, value: Any, valid: list[str], kind: str) -> bool:
        if not isinstance(value, str) or value in valid:
            return True
        self.add(path, f"undefined {kind}", show(value), f"{one_of(valid)} (the {kind} ids defined in this file)",
                 nearest(value, valid))
        return False

    def plugin(self, path: KeyPath, kind: str) -> None:
        name = _get(self.d, *path)
        names = plugin_names(kind)
        if isinstance(name, str) and names and name not in names:
            self.add(path, f"unknown {kind} plugin", show(name), one_of(names), nearest(name, names))

    # -- sections -----------------------------------------------------------------------------------
    def run(self) -> list[Problem]:
        conditions = self.unique_ids("conditions", kind="condition")
        self.unique_ids("participants", "strata", kind="stratum")
        instruments = self.unique_ids("instruments", kind="instrument")
        for index, _ in _items(self.d, "instruments"):
            self.unique_ids("instruments", index, "items", kind="item")
        self.check_conditions()
        self.check_counterbalance(conditions)
        self.check_questionnaires(conditions, instruments)
        self.check_scene()
        self.check_trial()
        self.check_participants()
        self.check_plugins()
        self.check_size()
        self.check_finite(self.d, ())
        return self.problems

    def check_size(self) -> None:
        conditions = _get(self.d, "conditions")
        reps = _get(self.d, "design", "repetitions")
        blocks = _get(self.d, "design", "blocks")
        reps = reps if isinstance(reps, int) and not isinstance(reps, bool) and reps >= 1 else 1
        blocks = blocks if isinstance(blocks, int) and not isinstance(blocks, bool) and blocks >= 1 else 1
        if isinstance(conditions, list) and reps <= MAX_REPETITIONS and blocks <= MAX_BLOCKS:
            total = len(conditions) * reps * blocks
            if total > MAX_TRIALS:
                self.add(("design", "repetitions"), "too many trials in one session",
                         f"{len(conditions)} conditions × {reps} repetitions × {blocks} blocks = {total}",
                         f"at most {MAX_TRIALS} trials per session")

    def check_finite(self, node: Any, path: KeyPath) -> None:
        """Every number anywhere (plugin params too) must be finite: .inf/.nan never reach a session."""
        if isinstance(node, float) and not math.isfinite(node):
            self.add(path, "number must be finite", show(node), "a finite number (not .inf or .nan)")
        elif isinstance(node, dict):
            for key, value in node.items():
                if not (path == () and isinstance(key, str) and key.startswith("x-")):
                    self.check_finite(value, (*path, key))
        elif isinstance(node, list):
            for index, value in enumerate(node):
                self.check_finite(value, (*path, index))

    def check_conditions(self) -> None:
        names = {str(n).lower() for _, c in _items(self.d, "conditions") if isinstance(c, dict)
                 for n in (c.get("id"), c.get("label")) if isinstance(n, str) and n}
        for index, cond in _items(self.d, "conditions"):
            if not isinstance(cond, dict):
                continue
            shown = cond.get("view_label")
            if isinstance(shown, str) and shown.strip().lower() in names:
                # the participant view shows it: a condition's own id or label would unblind the participant
                self.add(("conditions", index, "view_label"), "view label names a condition", show(shown),
                         "a neutral name that is no condition's id or label", "e.g. 'Session A'")
            manual, controller = cond.get("manual", False), cond.get("controller")
            if manual is True and controller is not None:
                self.add(("conditions", index, "controller"), "a manual condition runs no controller",
                         show(controller), "null (or manual: false)")
            elif manual is not True and controller is None and "controller" in cond:
                self.add(("conditions", index, "controller"), "controller missing",
                         "null", "a controller plugin name, or manual: true for a manual condition")
            elif manual is not True and "controller" not in cond:
                self.add(("conditions", index), "controller missing", "no 'controller' key",
                         "a controller plugin name, or manual: true for a manual condition")
            if manual is True and cond.get("params"):
                self.add(("conditions", index, "params"), "a manual condition has no controller parameters",
                         show(cond.get("params")), "an empty mapping")

    def check_counterbalance(self, conditions: list[str]) -> None:
        cb = _get(self.d, "counterbalance")
        if not isinstance(cb, dict):
            return
        base: KeyPath = ("counterbalance",)
        fixed = [c for c in cb.get("fixed_first") or [] if isinstance(c, str)] if isinstance(
            cb.get("fixed_first"), list) else []
        for i, cid in _items(cb, "fixed_first"):
            self.reference((*base, "fixed_first", i), cid, conditions, "condition")
        ordered_given = isinstance(cb.get("conditions"), list)
        if ordered_given:
            ordered = [c for c in cb["conditions"] if isinstance(c, str)]
            for i, cid in _items(cb, "conditions"):
                self.reference((*base, "conditions", i), cid, conditions, "condition")
                if cid in fixed:
                    self.add((*base, "conditions", i), "condition is both fixed first and counterbalanced",
                             show(cid), "each condition in exactly one of fixed_first and conditions")
            dupes = sorted({c for c in ordered if ordered.count(c) > 1})
            if dupes:
                self.add((*base, "conditions"), "condition listed twice", show(dupes[0]), "each condition once")
            missing = [c for c in conditions if c not in ordered and c not in fixed]
            if missing:
                self.add((*base, "conditions"), "condition never scheduled", show(missing[0]),
                         f"every condition in fixed_first or conditions ({', '.join(conditions)})")
        else:
            ordered = [c for c in conditions if c not in fixed]
        if len(set(fixed)) != len(fixed):
            self.add((*base, "fixed_first"), "condition listed twice", show(fixed), "each condition once")
        scheme = cb.get("scheme")
        orders = cb.get("orders")
        if scheme == "explicit":
            if orders is None:
                self.add(base, "explicit scheme needs orders", "no 'orders' key",
                         "orders: a list of condition orders", at_key=True)
            for i, order in _items(cb, "orders"):
                if not isinstance(order, list):
                    continue
                for j, cid in enumerate(order):
                    self.reference((*base, "orders", i, j), cid, conditions, "condition")
                valid = [c for c in order if isinstance(c, str)]
                if sorted(valid) != sorted(ordered) and all(c in conditions for c in valid):
                    self.add((*base, "orders", i), "order is not a permutation of the counterbalanced conditions",
                             "[" + ", ".join(valid) + "]", "each of " + ", ".join(ordered) + " exactly once")
        elif orders is not None and scheme is not None:
            self.add((*base, "orders"), f"orders are only used by the explicit scheme, not {scheme}", "orders",
                     "no 'orders' key (or scheme: explicit)", at_key=True)
        allocation = cb.get("allocation", "alternating")
        if cb.get("block_size") is not None and allocation != "blocked":
            self.add((*base, "block_size"), f"block_size is only used by allocation 'blocked', not {allocation!r}",
                     show(cb.get("block_size")), "no 'block_size' key (or allocation: blocked)", at_key=True)
        if allocation == "blocked" and cb.get("block_size") is None:
            self.add(base, "allocation 'blocked' needs block_size", "no 'block_size' key",
                     "block_size: participants per sequence (e.g. 6)", at_key=True)
        if scheme == "all_permutations" and len(ordered) > MAX_ALL_PERMUTATIONS:
            self.add((*base, "scheme"), "too many conditions for all permutations",
                     f"{len(ordered)} conditions ({math.factorial(len(ordered))} orders)",
                     f"at most {MAX_ALL_PERMUTATIONS} conditions; use williams or random")

    def check_questionnaires(self, conditions: list[str], instruments: list[str]) -> None:
        for index, adm in _items(self.d, "questionnaires"):
            if not isinstance(adm, dict):
                continue
            self.reference(("questionnaires", index, "instrument"), adm.get("instrument"), instruments,
                           "instrument")
            for j, cid in _items(adm, "conditions"):
                self.reference(("questionnaires", index, "conditions", j), cid, conditions, "condition")
            if adm.get("conditions") is not None and adm.get("when") not in ("after_trial", "after_condition"):
                self.add(("questionnaires", index, "conditions"),
                         f"conditions only restrict after_trial or after_condition, not {adm.get('when')!r}",
                         show(adm.get("conditions")), "no 'conditions' key here", at_key=True)
        for index, inst in _items(self.d, "instruments"):
            if not isinstance(inst, dict):
                continue
            self.check_scale(("instruments", index, "scale"), inst.get("scale"))
            for j, item in _items(inst, "items"):
                if not isinstance(item, dict):
                    continue
                self.check_scale(("instruments", index, "items", j, "scale"), item.get("scale"))
                if item.get("scale") is None and inst.get("scale") is None:
                    self.add(("instruments", index, "items", j), "item has no scale", "no 'scale' on the item or"
                             " its instrument", "a scale on the instrument (or on the item)")

    def check_scale(self, path: KeyPath, scale: Any) -> None:
        if not isinstance(scale, dict):
            return
        points, start = scale.get("points"), scale.get("start", 1)
        anchors = scale.get("anchors")
        if not (isinstance(points, int) and isinstance(start, int) and points >= 2 and isinstance(anchors, dict)):
            return
        codes = range(start, start + points)
        for code in anchors:
            if isinstance(code, int) and code not in codes:
                self.add((*path, "anchors", code), "anchor code outside the scale", show(code),
                         f"a code from {start} to {start + points - 1}", at_key=True)

    def check_scene(self) -> None:
        placement = _get(self.d, "scene", "placement")
        if isinstance(placement, dict):
            base: KeyPath = ("scene", "placement")
            sites, items = placement.get("sites"), placement.get("items")
            rule = placement.get("differ_from_previous", "assignment")
            if isinstance(sites, int) and isinstance(items, list):
                if len(items) > sites:
                    self.add((*base, "items"), "more items (tumours) than sites (holes)",
                             f"{len(items)} items in {sites} sites", f"at most {sites} items")
                elif rule == "every_item" and sites < 2:
                    self.add((*base, "differ_from_previous"), "every item cannot move with a single site",
                             show(rule), "'assignment' or 'none', or more sites")
                elif rule == "assignment" and math.perm(sites, len(items)) < 2:
                    self.add((*base, "differ_from_previous"), "only one placement exists, it cannot differ",
                             show(rule), "'none', or more sites")
            if isinstance(items, list):
                dupes = sorted({str(i) for i in items if items.count(i) > 1})
                if dupes:
                    self.add((*base, "items"), "item listed twice", show(dupes[0]), "each item once")
        orientation = _get(self.d, "scene", "orientation")
        if isinstance(orientation, dict):
            choices = orientation.get("choices_deg")
            if isinstance(choices, list) and len(set(map(str, choices))) != len(choices):
                self.add(("scene", "orientation", "choices_deg"), "orientation listed twice", show(choices),
                         "distinct angles")
            if orientation.get("differ_from_previous") is True and isinstance(choices, list) and len(choices) < 2:
                self.add(("scene", "orientation", "differ_from_previous"), "a single orientation cannot differ",
                         "true", "false, or at least 2 choices_deg")

    def check_trial(self) -> None:
        report = _get(self.d, "trial", "report")
        if isinstance(report, dict):
            kind = report.get("kind")
            if kind == "grid_cell" and report.get("grid") is None:
                self.add(("trial", "report"), "a grid_cell report needs a grid", "no 'grid' key",
                         "grid: {columns: N, rows: M}")
            if kind == "none" and report.get("hit_radius") is not None:
                self.add(("trial", "report", "hit_radius"), "nothing is reported, so no hit radius applies",
                         show(report.get("hit_radius")), "no 'hit_radius' key (or a report kind)", at_key=True)
        requests = _get(self.d, "trial", "requests")
        requests = requests if isinstance(requests, list) else ["report", "finish"]
        for index, cond in _items(self.d, "conditions"):
            if isinstance(cond, dict) and cond.get("visual") == "on_request" and "scan" not in requests:
                self.add(("conditions", index, "visual"), "scans on request need the 'scan' request",
                         f"trial.requests {show(requests)}", "'scan' listed in trial.requests")

    def check_participants(self) -> None:
        strata = _get(self.d, "participants", "strata")
        total = _get(self.d, "participants", "target_n")
        if isinstance(strata, list) and isinstance(total, int):
            targets = [s.get("target_n") for s in strata if isinstance(s, dict)]
            if targets and all(isinstance(t, int) for t in targets) and sum(targets) != total:
                self.add(("participants", "target_n"), "target_n differs from the sum of the strata's target_n",
                         show(total), f"{sum(targets)} (= {' + '.join(map(str, targets))})")

    def check_plugins(self) -> None:
        for index, cond in _items(self.d, "conditions"):
            if isinstance(cond, dict) and cond.get("controller") is not None:
                self.plugin(("conditions", index, "controller"), "controller")
                if cond.get("manual") is not True:
                    self.params(("conditions", index), "controller", "controller")
        for path, kind in (
            (("devices", "hardware"), "device"),
            (("devices", "simulated"), "device"),
            (("scene",), "scene"),
            (("participants", "virtual"), "participant"),
        ):
            self.plugin((*path, "plugin"), kind)
            self.params(path, "plugin", kind)

    def params(self, owner: KeyPath, name_key: str, kind: str) -> None:
        """The values under ``<owner>.params`` against the parameters the plugin declares (``PARAMS``), so a
        bad value is reported here with its line instead of when the first trial builds the plugin."""
        name, params = _get(self.d, *owner, name_key), _get(self.d, *owner, "params")
        if not isinstance(name, str) or not isinstance(params, dict):
            return
        cls = _plugin_class(kind, name)
        if cls is None:
            return  # unknown or broken: reported by plugin() here and by the preflight
        for problem in declared_problems(cls, params):
            path = (*owner, "params", *problem.key)
            found = show(problem.key[-1]) if problem.at_key else show(_get(self.d, *path))
            self.add(path, f"{kind} {name!r}: {problem.what}", found, problem.allowed, problem.suggestion,
                     at_key=problem.at_key)


def cross_check(marked: MarkedData, filename: str) -> list[Problem]:
    """Every reference and feasibility problem in the raw protocol data."""
    if not isinstance(marked.data, dict):
        return []
    return _Checker(marked, filename).run()
