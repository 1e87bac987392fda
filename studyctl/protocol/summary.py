"""A readable plain-text summary of a protocol (``studyctl protocol show``)."""

from __future__ import annotations

import json
from typing import Any

from studyctl.protocol.schedule import Planner
from studyctl.protocol.schema import Protocol


def _params(params: dict[str, Any]) -> str:
    if not params:
        return "plugin defaults"
    text = json.dumps(params, separators=(", ", ": "), default=str)
    return text if len(text) <= 100 else text[:97] + "..."


def _seconds(value: float | None) -> str:
    if value is None:
        return "none"
    return f"{value:g} s" if value < 120 else f"{value:g} s ({value / 60:g} min)"


def describe_protocol(protocol: Protocol) -> str:
    """Several lines describing what the protocol makes participants do, in plain words."""
    p = protocol
    planner = Planner(p)
    lines = [f"{p.study.title}", f"  study id {p.study.id}, protocol version {p.study.version}"]
    if p.sha256:
        lines.append(f"  sha256 {p.sha256}")
    if p.study.reference:
        lines.append(f"  reference: {p.study.reference}")
    hw = p.devices.hardware.plugin if p.devices.hardware else "none"
    lines += ["", f"Devices: hardware {hw}; simulated {p.devices.simulated.plugin}"]
    parts = p.participants
    strata = ", ".join(f"{s.id}" + (f" (target {s.target_n})" if s.target_n else "") for s in parts.strata)
    lines.append(f"Participants: strata {strata}" + (f"; total target {parts.target_n}" if parts.target_n else ""))
    lines.append(f"  codes {parts.code_prefix}-…; withdrawn slots "
                 + ("go to the next enrollee" if parts.replace_withdrawn else "are not reused"))
    if parts.virtual:
        lines.append(f"  virtual participant: {parts.virtual.plugin}")
    lines += ["", f"Conditions ({len(p.conditions)}):"]
    for c in p.conditions:
        how = "manual (coordinator enters the outcome)" if c.manual else f"controller {c.controller}"
        lines.append(f"  {c.id:<14} {c.label}")
        lines.append(f"  {'':<14} {how}; visual {c.visual}; params {_params(c.params)}")
    cb = p.counterbalance
    lines += ["", f"Counterbalancing: {cb.scheme}" + (f", fixed first {', '.join(cb.fixed_first)}" if cb.fixed_first
                                                         else "")
              + f"; allocation {cb.allocation}" + (f" ({cb.block_size} per sequence)" if cb.allocation == "blocked"
                                                    else "")
              + ("; within each stratum" if cb.within_strata else "; across strata")]
    if planner.sequences is None:
        lines.append(f"  a seeded random order of {', '.join(planner.ordered)} per participant")
    else:
        lines.append(f"  {len(planner.sequences)} sequences:")
        for i, seq in enumerate(planner.sequences[:24]):
            lines.append(f"    {i + 1:>3}: {' → '.join(seq)}")
        if len(planner.sequences) > 24:
            lines.append(f"    … {len(planner.sequences) - 24} more")
    d = p.design
    lines.append(f"Design: {d.repetitions} trial(s) per condition in a row; {d.blocks} block(s)"
                 + (f", order {d.block_order}" if d.blocks > 1 else ""))
    t = p.trial
    lines += ["", "Trial:",
              f"  time limit {_seconds(t.time_limit_s)}; break {_seconds(t.break_s)} between {t.break_between}"]
    if t.familiarisation:
        f = t.familiarisation
        lines.append(f"  familiarisation up to {_seconds(f.max_s)} {f.when.replace('_', ' ')}"
                     + ("; can end early" if f.can_end_early else ""))
    r = t.report
    report = {"grid_cell": "a grid cell", "position": "a position", "none": "nothing (the final pose is the outcome)"}
    line = f"  participant reports {report[r.kind]}"
    if r.grid:
        line += f" on a {r.grid.columns}×{r.grid.rows} grid"
    if r.hit_radius is not None:
        line += f"; correct within {r.hit_radius:g} {'cell(s)' if r.kind == 'grid_cell' else 'mm'}"
    lines.append(line + ("; target count told" if r.count_known else "; target count not told"))
    lines.append(f"  requests allowed: {', '.join(t.requests)}")
    s = p.scene
    lines += ["", f"Scene: {s.plugin}; params {_params(s.params)}"]
    if s.placement:
        pl = s.placement
        lines.append(f"  {len(pl.items)} items ({', '.join(pl.items)}) in {pl.sites} sites, new placement every trial"
                     f" (differ from previous: {pl.differ_from_previous})")
    if s.orientation:
        o = s.orientation
        lines.append(f"  orientation from {', '.join(f'{a:g}°' for a in o.choices_deg)} per {o.per}"
                     + ("; always changes" if o.differ_from_previous else ""))
    if p.questionnaires:
        lines += ["", "Questionnaires:"]
        for a in p.questionnaires:
            inst = p.instrument(a.instrument)
            only = f" (conditions {', '.join(a.conditions)})" if a.conditions else ""
            lines.append(f"  {inst.id} v{inst.version}: {len(inst.items)} item(s), {a.when.replace('_', ' ')}{only}")
            for item in inst.items:
                sc = inst.scale_of(item)
                anchors = "; ".join(f"{k}={v}" for k, v in sorted(sc.anchors.items()))
                lines.append(f"    - {item.id}: {item.text} [{sc.points} points{': ' + anchors if anchors else ''}]")
    lines += ["", f"Resume: interrupted trial → {p.resume.interrupted_trial}; checkpoint per {p.resume.checkpoint}"]
    return "\n".join(lines)
