"""The seed-000 virtual palpator's parameters (:mod:`studyctl.participants.palpator`): every motor, perception and
decision parameter with its unit, range and source (CITED, CHOSEN or FITTED), as the population file
(``studyctl/populations/bio_inspired_palpation.yaml``) draws them per person and ``protocol check`` validates them."""

from __future__ import annotations

from studyctl.plugins.params import Param

NEVER = 30.0  # a stop level this high is never reached (the regulator gives ≤ 20 psi, the motor ≤ 12 m/s²)

PARAMS = (
    # -- motor ----------------------------------------------------------------------------------------
    Param("depth_mm", 4.0, 0.2, 20.0, unit="mm", source="FITTED: intended press depth (~2 N on the sponge; "
          "Pugh 2015: examiners differ widely in palpation force)"),
    Param("checkpoints", (0.4, 0.6, 0.8, 1.0), kind=tuple, source="CHOSEN: fractions of the target depth "
          "at which the feel is noted"),
    Param("depth_cv", 0.08, 0.0, 0.5, source="CHOSEN: press-to-press variability of depth (motor noise)"),
    Param("aim_sd_mm", 2.0, 0.0, 10.0, unit="mm", source="CHOSEN: scatter of the probe about the cell centre"),
    Param("press_speed_mm_s", 6.0, 0.5, 100.0, unit="mm/s", source="FITTED: indentation speed"),
    Param("speed_trial_cv", 0.10, 0.0, 1.0, source="CHOSEN: trial-to-trial variation of a person's pace "
          "(speed and move time), within person"),
    Param("hold_s", 0.4, 0.0, 5.0, unit="s", source="FITTED: dwell at the bottom of a press"),
    Param("move_s", 0.3, 0.02, 5.0, unit="s", source="FITTED: time to move to the next 20 mm cell "
          "(Fitts-type pointing with a robot master, ~0.3-1 s)"),
    Param("stop_balloon_psi", 30.0, 0.0, 30.0, unit="psi", source="FITTED: a balloon pressure felt as firm "
          "enough ends the descent (instruction: least force; a person presses until the feedback says enough, "
          "so a cue that grows early, as the bio-inspired balloon does, ends presses at a lower force); felt "
          "with the person's balloon Weber noise per press; 30 = never (the regulator gives ≤ 20)"),
    Param("stop_vibration_ms2", 30.0, 0.0, 30.0, unit="m/s²", source="FITTED: as stop_balloon_psi for "
          "vibration; 30 = never (the motor gives ≤ 12)"),
    Param("stop_min_seen_mm", 0.0, 0.0, 10.0, unit="mm", source="CHOSEN: a haptic cue only ends a press once "
          "the endoscope shows the tip has dented the sponge at least this deep (felt with the person's visual "
          "Weber noise each press): people press until they see contact, then stop where the feedback says "
          "enough, so a cue that is already strong at touch-down does not end a press before the tissue "
          "under the probe has been deformed (0 = no visual minimum; without a view the hand's believed depth "
          "is used)"),
    Param("stop_ratio", 0.0, 0.0, 10.0, source="FITTED: a press also stops when a cue exceeds this multiple of "
          "what normal tissue gave at its strongest (the running median of earlier presses; 0 = never): "
          "something under the probe already feels different, so pressing on only adds force"),
    Param("stop_match", "peak", kind=str, choices=("peak", "depth"), source="CHOSEN: what stop_ratio compares a "
          "cue with. peak: what plain tissue gave at its strongest (the running median of earlier presses' peaks), "
          "so a cue can pass it only near the bottom of a press; depth: what plain tissue gave at the same "
          "fraction of the intended depth (the running median of earlier unstopped presses' notes at that "
          "checkpoint), judged as each checkpoint is passed: softness is judged as the force felt for a given "
          "indentation (Srinivasan & LaMotte 1995, J Neurophysiol 73:88), so a spot that already pushes back "
          "harder part-way down is felt as different before the press is done"),
    Param("after_stop", "release", kind=str, source="CHOSEN: what a person does with the rest of a press's "
          "planned time when a strong cue ended the descent early: release (go on), hold (stay at that depth) "
          "or tap (re-probe the same spot, each tap ending where the cue says enough: feedback felt during "
          "the dynamic phase invites probing, paper §IV; people palpate at a steady rhythm, and the paper "
          "found no effect of the feedback on completion time, p = 0.684)"),
    Param("max_taps", 2, 0, 10, kind=int, source="CHOSEN: most extra taps after one stopped press"),
    Param("lift_rule", "planned", kind=str, choices=("planned", "settled"), source="CHOSEN: planned = lift after "
          "the planned hold; settled = also hold on while a felt cue still rises by a Weber step within settle_s "
          "(sampling goes on while the evidence changes: Gold & Shadlen 2007, Annu Rev Neurosci 30:535)"),
    Param("settle_s", 0.1, 0.02, 1.0, unit="s", source="CHOSEN: with lift_rule settled, the window over which a "
          "cue that rose by less than a Weber step counts as settled (~ a vibrotactile integration time)"),
    Param("settle_max_s", 1.0, 0.0, 5.0, unit="s", source="CHOSEN: with lift_rule settled, the longest a press "
          "is held past its planned hold for a cue still rising"),
    Param("look_s", 0.0, 0.0, 5.0, unit="s", source="FITTED: extra dwell to judge the instrument's yield by eye "
          "when a press gave no haptic sensation (visual judgement of deformation takes time)"),
    # -- perception -----------------------------------------------------------------------------------
    Param("balloon_threshold_psi", 0.19, 0.0, 20.0, unit="psi",
          source="CITED: static one-point pressure threshold of the index finger 0.13 ± 0.06 g/mm² "
                 "(= 0.19 ± 0.09 psi, CV 46 %, n = 35; research/virtual_participants.md §1)"),
    Param("balloon_weber", 0.10, 0.01, 2.0,
          source="CITED: force JND 7 % (Pang 1991), 10 % (Allin 2002), 18-19 % passive (Gueorguiev 2020)"),
    Param("vibration_threshold_ms2", 0.2, 0.0, 20.0, unit="m/s²",
          source="CITED: ~0.1 µm at 150-250 Hz (Brisben 1999; Verrillo) = 0.16-0.25 m/s²; varies with age"),
    Param("vibration_weber", 0.20, 0.01, 2.0, source="CITED: vibrotactile amplitude discrimination ≈ 20 %"),
    Param("visual_weber", 0.10, 0.01, 2.0,
          source="CITED: visual speed Weber ≈ 7 % (Vision Res 1988), pseudo-haptic stiffness JND 6-13.4 % "
                 "(Lécuyer); fractions vary considerably between people (J Vis 2018)"),
    Param("travel_weber", 0.22, 0.01, 2.0,
          source="CITED: compliance resolution 22 % once work and terminal-force cues are separated (Tan, "
                 "Durlach, Beauregard & Srinivasan 1995, Percept Psychophys 57:495): with a force target the "
                 "hand's travel is the stiffness cue (Fu, van Paassen & Mulder 2017)"),
    Param("visual_trust", 1.0, 0.0, 1.0, source="FITTED: weight a person gives the camera cue (0 ignores it)"),
    Param("learning", 0.0, 0.0, 0.8, source="CITED: most practice gain in lump detection comes within 1-2 "
          "sessions (Adams et al.); fraction of perceptual noise lost by the 4th trial"),
    # -- decision -------------------------------------------------------------------------------------
    Param("judge_spread", False, kind=bool, source="CHOSEN: whether a cell's evidence is judged against how "
          "much normal tissue varied over the survey (the robust SD of the first presses' percepts) when that "
          "exceeds the senses' own noise: in signal detection the criterion is set against the total noise of "
          "the non-signal stimuli, external and internal (Green & Swets 1966; Lu & Dosher 2008, external noise); "
          "a feedback that varies from press to press on plain sponge (the hand's depth varies by depth_cv) "
          "marks fewer plain cells as different. False: only the Weber noise of the senses"),
    Param("report_rule", "z", kind=str, choices=("z", "odds"),
          source="CHOSEN: what evidence a practised person needs to report a cell. z: report_z noise SDs, whatever "
          "was learnt. odds: after familiarisation, report when a tumour is more likely there than not, by the "
          "separation of tumour from sponge the practice showed and the share of marked cells on the example "
          "phantom (3 of 49): the likelihood-ratio criterion of signal detection with equal costs (Green & Swets "
          "1966); without practice (or when nothing was learnt) report_z"),
    Param("screen_z", 2.0, 0.0, 10.0, source="FITTED: re-probe a cell whose evidence exceeds this"),
    Param("report_z", 3.5, 0.0, 10.0, source="FITTED: confidence needed to report a cell"),
    Param("confirm_presses", 2, 0, 10, kind=int, source="CHOSEN: re-probes of a candidate cell"),
    Param("confirm_rounds", 1, 1, 10, kind=int, source="CHOSEN: a candidate whose evidence is still between "
          "screen_z and report_z after a round of re-probes is probed again, up to this many rounds "
          "(sequential sampling: weak cues are checked more often, Wald 1947); 1 = one round"),
    Param("sure_odds", 0.0, 0.0, 1000.0, source="CHOSEN: sequential sampling stops once the evidence reaches a "
          "bound (Wald 1947; Gold & Shadlen 2007, Annu Rev Neurosci 30:535): after practice (report_rule: odds), a "
          "cell whose sweep press already makes a tumour this many times likelier than not there is not re-probed "
          "(its evidence is past the bound; the report still takes the cell). 0 = every cell past screen_z is "
          "re-probed once, as before (measured: scripts/palpation_contact_time.py, re-probes of cells already past "
          "the report level are most of the presses that set tumour contact time apart between controllers)"),
    Param("dismiss_odds", 0.0, 0.0, 1.0, source="CHOSEN: the lower bound of Wald's sequential probability ratio "
          "test (Wald 1947; Gold & Shadlen 2007, Annu Rev Neurosci 30:535), the partner of sure_odds: after practice "
          "(report_rule: odds), a cell is probed again while a tumour there is neither this unlikely (odds below "
          "dismiss_odds) nor past the report level (or sure_odds); with equal error rates of 5 % the bounds are 19 "
          "and 1/19. How many cells stay undecided then follows from the separation the practice showed for this "
          "feedback, not from a fixed screen_z. 0 = screen_z, as before"),
    Param("max_reports", 0, 0, 49, kind=int, source="CHOSEN: at most this many cells are reported, the strongest "
          "first (0 = no limit); the example phantom shows 3 tumours, so people expect about that many"),
    Param("guess", "random", kind=str, source="CHOSEN: which cells a person reports when nothing stood out: "
          "random (distinct cells at random) or best (the cells whose evidence was strongest: in a forced choice "
          "an observer picks the alternative with the largest observation, the max rule of signal detection "
          "theory, Green & Swets 1966; the instruction was to report the tumours, so weak evidence still "
          "guides where)"),
    Param("familiarise", False, kind=bool, source="CITED: before each trial the paper's subjects had up to 5 min "
          "on an example phantom with the 3 tumour sites marked, to get used to the feedback (Methods II.D.3). "
          "True: the person practises there through the condition's device and controller (the engine's practice "
          "run), pressing each marked site and plain sponge practice_presses times, and then judges cells by the "
          "cues that told tumour from sponge, weighted by how much and how reliably they did "
          "(studyctl.participants.palpator_practice). False: no practice; cells judged by their strongest cue"),
    Param("cue_learning", "diagonal", kind=str, choices=("diagonal", "by_mark", "shrinkage"), source="CHOSEN: how "
          "practice weights the cues. diagonal: each by its mean difference over its variance, kept when t >= 2 "
          "(independent cues, Ernst & Banks 2002). by_mark: the same with the variance taken within each marked site "
          "(Fisher's pooled within-class variance, Duda, Hart & Stork 2001: the practice shows which mark is which "
          "tumour, so their differences are not noise). shrinkage: one linear discriminant over all noted cues, "
          "correlations shrunk towards none by the data-chosen intensity (Schäfer & Strimmer 2005), no cue weighted "
          "against its move"),
    Param("practice_presses", 4, 1, 20, kind=int, source="CHOSEN: presses on each marked site in practice (and as "
          "many on plain sponge, at different cells); 3 sites x 4 + 12 plain presses take ~20 s of the 5 min"),
    Param("practice_rule", "fixed", kind=str, choices=("fixed", "until_learnt"), source="CITED budget, CHOSEN rule: "
          "how long each mark is practised. fixed: practice_presses presses on each mark. until_learnt: after those, "
          "the person keeps pressing one mark at a time (each press followed by one on a plain cell) until on some cue "
          "the mark differs from plain sponge by t >= 2 (the bar a cue must pass to be learnt at all) or its equal "
          "share of the practice time left is used; the budget is the practice's time limit, the paper's up to 5 "
          "min on the example phantom (Methods II.D.3)"),
    Param("learnt_bar", "any_cue", kind=str, choices=("any_cue", "combined"), source="CHOSEN: with practice_rule "
          "until_learnt, when a mark counts as learnt. any_cue: some single cue differs from plain sponge by t >= 2. "
          "combined: the evidence the trial decision uses (cue weights learnt by cue_learning, here from the other "
          "marks' and the plain presses so far: held out, so the mark's own noise cannot pass it) is higher on this "
          "mark's presses than on the plain presses by t >= 2 (the plain presses' spread); one noisy cue out of ~11 "
          "no longer ends a mark's practice (optional stopping)"),
    Param("guesses", 3, 0, 20, kind=int, source="CHOSEN: cells reported when nothing stood out (the paper's "
          "trials had 3 tumours; subjects were told to report)"),
    Param("cell_mm", 20.0, 1.0, 100.0, unit="mm", source="used when the trial's public info has no grid size"),
    Param("columns", 7, 1, 50, kind=int, source="used when the trial's public info has no grid"),
    Param("rows", 7, 1, 50, kind=int, source="used when the trial's public info has no grid"),
)
