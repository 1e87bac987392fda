"""Every perception, motor and decision parameter of the virtual needle operator, with unit, range and source.

Between-person traits are ordinary parameters: a population file (``studyctl/populations/needle_insertion.yaml``)
draws them once per virtual person and hands them to the operator's constructor; the defaults here are the
population's typical (median) person. Within-person trial-to-trial variation is itself a parameter
(``speed_trial_cv``, ``read_trial_cv``), applied by the operator with the trial's random stream.

Sources: ``CITED:`` a published value (see shared/research/virtual_participants.md), ``CHOSEN:`` our choice and
why, ``FITTED``: set by calibrating seed 001's population to the paper's numbers (see the population file's
``calibration`` block for which numbers were fitted and which were held out).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from studyctl.plugins.params import Param, validate_params

Vec = tuple[float, float, float]

PARAMS = (
    # ---------------------------------------------------------------- motor
    Param("insert_speed_mm_s", 7.0, 1.0, 40.0, unit="mm/s",
          source="FITTED: a person's steady needle advance in liver (between-person trait; ~5–20 mm/s)"),
    Param("approach_speed_ratio", 2.5, 1.0, 8.0, unit="×",
          source="CHOSEN: free-space reaches are faster than advancing through tissue; also the fastest it advances "
                 "inside a guidance channel it trusts (then the advance is a reach along the line)"),
    Param("final_speed_ratio", 0.55, 0.05, 1.0, unit="×",
          source="CHOSEN: corrections near the target are slower than the insertion"),
    Param("speed_trial_cv", 0.1, 0.0, 0.6, unit="log-SD",
          source="CHOSEN: within-person trial-to-trial variation of movement speed"),
    Param("speed_noise", 0.15, 0.0, 1.0, unit="relative",
          source="CHOSEN: slow within-trial fluctuation of the advance speed (signal-dependent motor noise)"),
    Param("realtime_speed_gain", 1.0, 0.2, 3.0, unit="×",
          source="FITTED: speed with a live image relative to steering between scans"),
    Param("arm_stiffness_n_per_m", 300.0, 50.0, 2000.0, unit="N/m",
          source="CHOSEN: the stiffness of its own grip on the pen, as the simulated hand's (devices/force3d "
                 "hand_stiffness_n_per_m, relaxed grip 100–500 N/m): a lateral slip of the hand moves the tip by "
                 "k_arm/(k_arm + k_channel) of it inside a channel of stiffness k_channel"),
    Param("motor_noise_mm", 0.3, 0.02, 3.0, unit="mm",
          source="CHOSEN: lateral wobble of the hand set-point (stationary SD; smoothness trait)"),
    Param("motor_tau_s", 0.5, 0.05, 5.0, unit="s", source="CHOSEN: correlation time of that wobble"),
    Param("orientation_sd_deg", 1.5, 0.0, 10.0, unit="deg",
          source="CHOSEN: error in pointing the pen along the planned path"),
    Param("decision_hz", 100.0, 10.0, 1000.0, unit="Hz", source="CHOSEN: motor/perceptual update rate"),
    Param("reaction_s", 0.18, 0.08, 0.8, unit="s",
          source="CHOSEN: simple reaction to a felt force ~0.15–0.2 s; CITED for its spread: tactile stimulus "
                 "factors shift RTs by 20–300 ms (Bao et al. 2019, PLOS ONE)"),
    # ---------------------------------------------------------------- vision
    Param("scan_read_s", 2.2, 0.5, 15.0, unit="s",
          source="FITTED: looking at a requested scan before acting on it (between-person trait)"),
    Param("plan_read_extra_s", 1.0, 0.0, 10.0, unit="s",
          source="CHOSEN: the first scan also has to be planned on (marker → tumour path)"),
    Param("confirm_read_ratio", 0.4, 0.2, 1.0, unit="×",
          source="FITTED: reading time of a check while a haptic cue of the scenario is trusted, relative to a "
                 "scan read without that expectation"),
    Param("read_trial_cv", 0.15, 0.0, 0.8, unit="log-SD",
          source="CHOSEN: within-person trial-to-trial variation of reading time"),
    Param("visual_period_s", 0.25, 0.02, 2.0, unit="s", source="CHOSEN: real-time view: how often it is read"),
    Param("realtime_view_delay_s", 0.0, 0.0, 1.0, unit="s",
          source="CHOSEN (0: off, a look at the live view is acted on at once): with the live view it acts on what "
                 "a look showed this long after the look, against where it feels its hand by then, so a tip seen "
                 "while moving is taken to be where it was. Visual feedback of the moving hand corrects a reach only "
                 "after 117 ms across the movement and 130-200 ms along it (Saunders & Knill 2005, Exp Brain Res "
                 "162:458-473). A requested scan is read holding still, where the delay costs nothing"),
    Param("rt_tolerance_mm", 0.0, 0.0, 5.0, unit="mm",
          source="CHOSEN (0: off, every look re-aims the tip): with a live view it corrects its tip sideways only "
                 "once the image shows it this far off where it feels it is; below that it keeps steering by feel. "
                 "With continuous vision people plan less carefully and rely on discrete online corrections "
                 "(two-component model, Elliott et al. 2010, Psychol Bull 136:1023-1044); human visuomotor control "
                 "is intermittent, acting when a seen error passes a threshold (Gawthrop, Loram, Lakie & Gollee "
                 "2011, Biol Cybern 104:31-51). Only until it is margin_mm short of the believed tumour: closer in it "
                 "is homing in and corrects every seen error (the same model's visually controlled homing phase)"),
    Param("rt_tolerance_reach", 0.0, 0.0, 1.0, unit="0/1",
          source="CHOSEN (0: off): 1 lets rt_tolerance_mm's seen sideways error go also while it reaches onto the "
                 "incision, not only once inserting: reach and insertion are one aimed movement at the tumour, whose "
                 "initial impulse runs without fine visual control (two-component model, Elliott et al. 2010); a "
                 "person who watches the tip live has no reason to line up exactly before entering, since it can "
                 "steer later, while one who pays a scan for each look lines up first. Measured in session 32: with "
                 "0, RT entered the liver 0.77 mm off the path against BL's 1.27 mm"),
    # ---------------------------------------------------------------- position sense
    Param("proprio_drift", 0.15, 0.0, 1.0, unit="mm/√mm",
          source="CHOSEN: position-sense drift per √mm moved, per axis (between-person trait)"),
    Param("believed_drift", 0.0, 0.0, 1.0, unit="mm/√mm",
          source="CHOSEN (0: off, its uncertainty grows at its true proprio_drift): the drift it believes its "
                 "position sense has, for everyone the same typical value; its lateral uncertainty, and so how "
                 "often it stops to check (recheck_mm), grows at this rate while its sense drifts at its own. "
                 "With the true rate, checks per mm went as proprio_drift^2 / recheck_mm^2 and a cautious person "
                 "with a poor position sense took 10-14 scans per trial (seed 001 v5 candidates, seed 7)"),
    # ---------------------------------------------------------------- force perception
    Param("force_weber", 0.1, 0.02, 0.5, unit="fraction",
          source="CITED: force JND ≈ 7 % (Pang, Tan & Durlach 1991), ≈ 10 % on a force-feedback device "
                 "(Allin, Matsuoka & Klatzky 2002); 75 %-JND 0.18–0.19 passive (Gueorguiev et al. 2020)"),
    Param("force_threshold_n", 0.12, 0.01, 1.0, unit="N",
          source="CHOSEN: smallest axial force rise noticed while sliding in; spread CITED from the static "
                 "pressure threshold's between-person CV ≈ 46 % (n = 35)"),
    Param("force_noise_n", 0.02, 0.0, 0.5, unit="N", source="CHOSEN: moment-to-moment noise on the felt force"),
    Param("radial_threshold_n", 0.08, 0.01, 1.0, unit="N",
          source="CHOSEN: a lateral push this strong is felt as guidance (spread as force_threshold_n)"),
    Param("follow_gain_mm_per_ns", 3.0, 0.0, 20.0, unit="mm/(N·s)",
          source="CHOSEN: how readily it yields to a felt guidance force"),
    Param("realtime_follow_weight", 1.0, 0.0, 1.0, unit="fraction",
          source="CHOSEN (1: off, the push is followed as without the view): with the live view, the share of a felt "
                 "lateral guidance push the hand still yields to. Seeing the tip, it takes its lateral position from "
                 "the image, the more reliable cue, and discounts the felt push: cues combine weighted by their "
                 "reliability and vision dominates when it is the more precise (Ernst & Banks 2002, Nature "
                 "415:429-433)"),
    Param("wall_n", 0.3, 0.01, 5.0, unit="N",
          source="CHOSEN: a lateral force this strong feels like a firm channel wall"),
    Param("probe_mm", 0.0, 0.0, 5.0, unit="mm",
          source="CHOSEN: in the first trial of a scenario, lined up over the incision, it pushes its hand this far "
                 "sideways and back to feel how firmly it is held (the pressure exploratory procedure by which "
                 "people judge compliance: Lederman & Klatzky 1987, Cogn. Psychol. 19:342-368); 0: it never "
                 "probes. Inside the guidance's 1 mm tolerance no force is felt, so a steady hand learns of a "
                 "stiff channel only by pushing"),
    Param("wall_travel_mm", 0.6, 0.05, 5.0, unit="mm",
          source="CHOSEN: a lateral force that grows from just noticeable to wall_n while the hand moves sideways "
                 "less than this feels like a firm wall (stiff guidance), more like a soft pull: a stiffness "
                 "criterion between the BL spring (100 N/m: ~2 mm for 0.2 N) and the EG one (1000 N/m: ~0.2 mm); "
                 "a 10x stiffness ratio is far above the compliance JND of ~22 % (Tan et al. 1995)"),
    # ---------------------------------------------------------------- decisions and learning
    Param("entry_scan_mm", 0.9, 0.1, 10.0, unit="mm",
          source="CHOSEN: scan before entering when the lateral uncertainty exceeds this"),
    Param("recheck_mm", 1.6, 0.2, 10.0, unit="mm",
          source="FITTED: scan during insertion when the lateral uncertainty exceeds this (caution trait)"),
    Param("finish_mm", 0.8, 0.1, 5.0, unit="mm",
          source="FITTED: finish without a confirming scan only below this uncertainty (confidence trait)"),
    Param("accept_mm", 2.0, 0.5, 10.0, unit="mm",
          source="CHOSEN: a tip this close to the centroid touches the 2.5 mm tumour on the image: done"),
    Param("margin_mm", 6.0, 0.0, 30.0, unit="mm",
          source="CHOSEN: stop this far before the believed target to check, unless a cue is trusted"),
    Param("overshoot_mm", 3.0, 0.0, 20.0, unit="mm",
          source="CHOSEN: when trusting a cue, advance at most this far past the believed target"),
    Param("cue_trust_rate", 0.8, 0.0, 1.0, unit="fraction",
          source="CHOSEN: learning rate of trust in the axial cue: a cue confirmed by a scan moves trust this "
                 "fraction of the way to 1 (a wrong one towards 0); trusted from 0.5 (between-person trait)"),
    Param("cue_learn_late", 0.0, 0.0, 1.0, unit="0/1",
          source="CHOSEN (0: off, only a cue it stopped on teaches trust): 1 lets a cue it felt too late to stop on "
                 "(the leg ended within its reaction time) teach trust as well, judged by the scan that follows: the "
                 "felt rise and the image of the tip at the tumour come together as for a cue it stopped on. Trust in "
                 "an aid grows with its observed reliability (Lee & See 2004, Hum Factors 46:50-80), and what is "
                 "observed is the felt push, not whether the hand stopped for it. Measured in session 33 (12 v6 "
                 "people, first ES trial): 1 of 6 correction legs that ended without a cue stop had felt the cue"),
    Param("cue_reach", 0.0, 0.0, 1.0, unit="0/1",
          source="CHOSEN (0: off, it advances at its insertion pace whatever it trusts): 1 lets a person who trusts "
                 "the scenario's axial cue advance at its free-reach pace (approach_speed_ratio, the cap inside a "
                 "trusted channel too) until margin_mm short of the planned depth, then feel for the tumour at its "
                 "own pace as before: the cue, not its position sense, will mark where to stop, so the advance need "
                 "not be paced for stopping at an unseen depth (reliance follows trust, Lee & See 2004; the paper's "
                 "participants felt 'increased confidence in proceeding toward the target', Selim et al. 2024). "
                 "Faster, its hand slips more sideways (signal-dependent motor noise): the cost is simulated, not set"),
    Param("cue_by_feel", 0.0, 0.0, 1.0, unit="0/1",
          source="CHOSEN (0: off, trust in the axial cue is learnt per scenario label from any cue it stopped on): 1 "
                 "makes the trust belong to the cue as felt, not to the scenario's name. Only a clear cue, one that "
                 "rose to cue_clear_ratio times the rise it needed to notice, teaches trust: a rise near its own "
                 "threshold cannot be told from the liver's own bumps, and natural tip forces are 'insufficient to "
                 "clearly perceive and identify deep-tissue structures such as tumors' (Selim et al. 2024, who "
                 "gave BL's tumour only slightly more friction and cutting force for that reason). A scenario in "
                 "which it has felt a clear cue is trusted as far as that cue is (the enhanced tumour of ES and of "
                 "ESG feels the same: trust learnt in one carries to the other once it has felt it there); one "
                 "where it has felt only a faint one, or none, is not (Lee & See 2004: trust follows the aid's "
                 "observed reliability)"),
    Param("cue_clear_ratio", 2.0, 1.0, 10.0, unit="ratio",
          source="CHOSEN: a felt cue is clear when its peak rise over the liver's baseline reached this many times "
                 "the rise the person needed to notice it (max(force_threshold_n, force_weber x baseline)); at twice "
                 "the detection threshold a force step is noticed nearly every time, at the threshold only some of the "
                 "time (a psychometric function rises from chance to near certainty over about a factor of two)"),
    Param("guide_trust_rate", 0.8, 0.0, 1.0, unit="fraction",
          source="CHOSEN: learning rate of trust in a felt guidance channel, per trial in which it was felt"),
    Param("preentry_mm", 8.0, 0.0, 40.0, unit="mm",
          source="CHOSEN: where to put the tip above the incision point before entering"),
    Param("home_x_mm", 0.0, -200.0, 200.0, unit="mm", source="CHOSEN: hand position at the start of a trial"),
    Param("home_y_mm", 0.0, -200.0, 200.0, unit="mm", source="CHOSEN"),
    Param("home_z_mm", 38.0, -200.0, 200.0, unit="mm", source="CHOSEN"),
)  # fmt: skip
DEFAULTS: dict[str, float] = {p.name: p.default for p in PARAMS}


@dataclass(frozen=True)
class OperatorParams:
    """The checked :data:`PARAMS` of one operator (field names are the parameter names)."""

    insert_speed_mm_s: float
    approach_speed_ratio: float
    final_speed_ratio: float
    speed_trial_cv: float
    speed_noise: float
    realtime_speed_gain: float
    arm_stiffness_n_per_m: float
    motor_noise_mm: float
    motor_tau_s: float
    orientation_sd_deg: float
    decision_hz: float
    reaction_s: float
    scan_read_s: float
    plan_read_extra_s: float
    confirm_read_ratio: float
    read_trial_cv: float
    visual_period_s: float
    realtime_view_delay_s: float
    rt_tolerance_mm: float
    rt_tolerance_reach: float
    proprio_drift: float
    believed_drift: float
    force_weber: float
    force_threshold_n: float
    force_noise_n: float
    radial_threshold_n: float
    follow_gain_mm_per_ns: float
    realtime_follow_weight: float
    wall_n: float
    probe_mm: float
    wall_travel_mm: float
    entry_scan_mm: float
    recheck_mm: float
    finish_mm: float
    accept_mm: float
    margin_mm: float
    overshoot_mm: float
    cue_trust_rate: float
    cue_learn_late: float
    cue_reach: float
    cue_by_feel: float
    cue_clear_ratio: float
    guide_trust_rate: float
    preentry_mm: float
    home_x_mm: float
    home_y_mm: float
    home_z_mm: float

    @classmethod
    def from_mapping(cls, params: Mapping[str, Any] | None) -> OperatorParams:
        """Checked against :data:`PARAMS` (unknown names, types, ranges): one error naming the parameter."""
        p = validate_params("participant virtual_needle_operator", params, PARAMS)
        return cls(**{k: float(v) for k, v in p.items()})

    @property
    def home(self) -> Vec:
        return (self.home_x_mm, self.home_y_mm, self.home_z_mm)
