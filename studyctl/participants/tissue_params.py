"""The virtual tissue palpator's parameters (:mod:`studyctl.participants.tissue_palpator`): every perception and
behaviour parameter with its unit, range and source (CITED, CHOSEN or FITTED), as the populations declare them."""

from __future__ import annotations

from studyctl.plugins.params import Param

PARAMS = (
    # ---- search strategy (between-subject traits: how densely a person surveys)
    Param("line_spacing_mm", 8.0, low=1.0, high=50.0, unit="mm",
          source="CHOSEN: survey lines closer than a nodule's reach; spread between people is the systematic "
          "(dense) vs quick (sparse) survey (Saunders et al. 1986: coverage differed with the search pattern)"),
    Param("press_spacing_mm", 8.0, low=1.0, high=50.0, unit="mm",
          source="CHOSEN: every other line shifted by half this (a staggered lattice)"),
    Param("margin_mm", 6.0, low=0.0, high=50.0, unit="mm", source="CHOSEN: stay off the tissue's edge"),
    # ---- motor behaviour
    Param("press_depth_mm", 5.0, low=0.5, high=15.0, unit="mm", source="CHOSEN: inside the 2-7 mm maps"),
    Param("depth_noise_mm", 0.2, low=0.0, high=5.0, unit="mm", source="CHOSEN: press-to-press depth scatter"),
    Param("hover_mm", 2.0, low=0.5, high=30.0, unit="mm", source="CHOSEN: lift just clear of the surface"),
    Param("move_speed_mm_s", 60.0, low=1.0, high=500.0, unit="mm/s",
          source="CHOSEN: hand transport between presses, before tempo"),
    Param("press_speed_mm_s", 40.0, low=1.0, high=500.0, unit="mm/s",
          source="CHOSEN: indentation speed before tempo (seed 003 scanned at 30 mm/s)"),
    Param("gain_per_s", 8.0, low=0.5, high=200.0, unit="1/s",
          source="CHOSEN: 125 ms hand-eye time constant at tempo 1, stable with the device's spring-held hand (4 Hz)"),
    Param("tempo", 1.0, low=0.1, high=10.0,
          source="FITTED: a person's motor tempo (between-subject trait): multiplies the move and press speeds and "
          "divides the settle time and the shortest dwell"),
    Param("tool_tempo", 1.0, low=0.2, high=5.0, source=(
        "CHOSEN: a person's tempo with a tool in the hand (a stylus: the device's feedback does not say direct_touch) "
        "relative to its bare-finger tempo; multiplies the tempo in such trials (a between-subject trait: people "
        "differ in how much a stylus slows them, so haptic and manual times per person are not one fixed ratio); "
        "1: the same tempo with and without a tool")),
    Param("tempo_trial_cv", 0.0, low=0.0, high=1.0,
          source="CHOSEN: trial-to-trial (within-person) variation of the tempo, log-normal with this CV, drawn "
          "from the trial's stream"),
    Param("practice_gain", 0.0, low=0.0, high=2.0,
          source="CHOSEN: learning: the tempo grows by this fraction over a session's trials, half of it by the "
          "second trial (Adams et al.: most of the practice gain in lump detection came within 1-2 sessions)"),
    Param("hold_gain_ratio", 0.25, low=0.0, high=1.0,
          source="CHOSEN: while holding a press the depth is corrected this much more slowly than while pressing "
          "(a 4/s loop at tempo 2 stays clear of the 4-5 Hz resonance of a spring-held hand on the tissue)"),
    Param("press_adaptation", 0.0, low=0.0, high=1.0,
          source="CHOSEN: how much of the gap between the hand's travel and the watched point's in the tissue (cursor "
          "slowed by pseudo-haptics, hand pushed back by rendered force) one press adapts the pressing gain by; "
          "people adapt to a changed visuomotor gain within a few movements (Krakauer, Pine, Ghilardi & Ghez 2000, "
          "J Neurosci 20:8916); 0: never (the press slows with the yield)"),
    Param("press_steer", "seen", kind=str, choices=("seen", "felt"),
          source="CHOSEN: the switch (its direction CITED): what a press's depth is steered by when a cursor is "
          "watched. seen: the cursor's depth below the visible surface, throughout. felt: once the push is felt (force "
          "feedback), "
          "the hand's own travel since that moment (proprioception); the indentation a stiffness is judged against is "
          "still read off the cursor. For movement in depth people weight what they feel over what they see (van "
          "Beers, Wolpert & Haggard 2002, Curr Biol 12:834), and a felt contact marks the surface in the hand's own "
          "frame. Changes nothing "
          "without a felt push (PHF) or without a cursor (by hand), nor where the cursor follows the hand (FF); with "
          "PHF+FF the press no longer waits for a slowed cursor that the release-on-retract push ratchets back up"),
    Param("max_press_boost", 4.0, low=1.0, high=20.0,
          source="CHOSEN: the pressing gain is raised at most this much by adaptation"),
    Param("tolerance_mm", 0.3, low=0.01, high=5.0, unit="mm", source="CHOSEN: depth accuracy at the press bottom"),
    Param("settle_s", 0.05, low=0.0, high=5.0, unit="s", source="CHOSEN: a pause before pressing, at tempo 1"),
    Param("phase_timeout_s", 1.5, low=0.1, high=30.0, unit="s", source="CHOSEN: a stuck movement is abandoned"),
    Param("dwell_s", 0.08, low=0.0, high=5.0, unit="s",
          source="CHOSEN: the shortest hold at a press bottom (a clear cue is judged at once), at tempo 1"),
    # ---- perception (Weber fractions are the SD of one judgement made over judge_time_s)
    Param("force_weber", 0.06, low=0.0, high=1.0,
          source="CITED: force JND 7 % (Pang, Tan & Durlach 1991) to 10 % on a force-feedback device (Allin et "
          "al. 2002); σ of one judgement = JND/(√2·0.954) at 75 % correct, 8 % → 0.06"),
    Param("depth_weber", 0.05, low=0.0, high=1.0,
          source="CHOSEN: reading the indentation depth (seen on screen, or felt by the hand's position)"),
    Param("visual_weber", 0.074, low=0.0, high=1.0,
          source="CITED: visual speed Weber fraction ≈ 7 % at 4-64 deg/s (Vision Res 1988;28:1323), varying "
          "considerably between people (J Vis 2018;18(6):15); 10 % JND → σ 0.074"),
    Param("hand_weber", 0.0, low=0.0, high=1.0,
          source="CHOSEN: the hand's own travel, judged by proprioception, against which the cursor's slowing is "
          "seen (the cursor cue compares the two; 0: the hand's travel is known exactly)"),
    Param("judge_time_s", 0.3, low=0.01, high=10.0, unit="s",
          source="CHOSEN: the hold over which one judgement has the Weber fractions above; a longer hold averages "
          "the sensory noise down as 1/√time (evidence accumulation, Ratcliff & McKoon 2008)"),
    Param("press_precision", 0.0, low=0.0, high=1.0,
          source="FITTED: decision criterion per press: the person holds a press until its stiffness judgement "
          "(all cues fused) has this SD or less, at most max_dwell_s (0: always the shortest dwell)"),
    Param("steady_rate_n_s", 2.0, low=0.01, high=100.0, unit="N/s",
          source="CHOSEN: a push whose average changes faster than this is felt as still settling (0.1 N in 50 ms, "
          "about a force JND at 1 N); the judgement starts once it is steady"),
    Param("steady_window_s", 0.2, low=0.01, high=2.0, unit="s",
          source="CHOSEN: steadiness is judged by comparing the push averaged over the last half of this window "
          "with the half before; 0.1 s halves span three cycles of the ~30 Hz on/off push that seed 003's "
          "release-on-retract rendering gives a held stylus, and people cannot modulate a force faster than "
          "5-10 Hz (Brooks 1990, telerobotic response requirements), so a judgement of 'steady' takes this long"),
    Param("judge_from_bottom", False, kind=bool,
          source="CHOSEN: whether the hold that makes one press's judgement precise runs from the press bottom "
          "(true: the push is felt while it settles, evidence accumulating over the whole hold, Ratcliff & McKoon "
          "2008; the press ends once the hold is over and the push is steady) or only from when the push is "
          "steady (false: the settling time is added to every hold)"),
    Param("max_dwell_s", 2.0, low=0.0, high=30.0, unit="s", source="CHOSEN: nobody holds one press longer"),
    Param("force_trust", 1.0, low=0.0, high=1.0,
          source="CHOSEN: the share of the force cue's information a person uses (1: statistically optimal "
          "fusion, Ernst & Banks 2002)"),
    Param("cursor_trust", 1.0, low=0.0, high=1.0,
          source="FITTED: the share of the cursor cue's information a person uses: a visual-only stiffness cue "
          "is believed less than a felt one (the pseudo-haptic illusion weakens with exposure, Front VR 2024)"),
    Param("ratio_window_mm", 2.0, low=0.2, high=20.0, unit="mm",
          source="CHOSEN: the cursor's slowing is judged over the last part of its travel"),
    Param("slide_survey", False, kind=bool,
          source="CITED: the behaviour: where a press shows the cursor lagging the hand (pseudo-haptics), the rest "
          "of the survey slides the tool along each line at depth and reads the cursor's sideways slowing (seed 003 "
          "§2.4: people palpate by sliding and pressing; a cursor slowing sideways reads as a bump, Lécuyer, "
          "Burkhardt & Etienne 2004); it needs the controller's lateral_ratio: normal; false: presses only"),
    Param("slide_speed_mm_s", 30.0, low=1.0, high=500.0, unit="mm/s",
          source="CHOSEN: the hand's sliding speed before tempo (seed 003's rolling indentation scanned at 30 mm/s)"),
    Param("slide_window_mm", 4.0, low=0.5, high=50.0, unit="mm",
          source="CHOSEN: one sideways-slowing judgement per this much cursor travel (under the 6 mm nodule's size)"),
    Param("slide_fusion", "stouffer", kind=str, choices=("stouffer", "reliability", "pooled"),
          source="CITED: how a slid survey adds its cues' evidence (z in each cue's own noise SDs): stouffer, with "
          "equal weights (times trust); reliability, each weighted by the detectability it showed over this trial's "
          "survey, sqrt(mean z² - 1) of its own records (the ideal observer's weights for independent cues, Green & "
          "Swets 1966; the detection form of Ernst & Banks 2002); pooled, the same amplitude pooled over the "
          "person's slid trials so far and shrunk towards equal weights by cue_prior_windows (cue weights are "
          "learnt with exposure: Ernst, Banks & Bülthoff 2000; Atkins, Fiser & Jacobs 2001)"),
    Param("cue_prior_windows", 100.0, low=0.0, high=100000.0, unit="windows",
          source="CHOSEN: slide_fusion pooled: the person's starting belief that its slid cues are equally reliable "
          "counts as much as this many slid windows of experience (about half of one slid survey's 139-288)"),
    Param("cue_excess", "spread", kind=str, choices=("spread", "stiffer"),
          source="CHOSEN: slide_fusion reliability/pooled: what a cue is judged to have shown: spread, mean z² - 1 "
          "(any spread beyond the robust noise SD); stiffer, mean z·|z| (the stiffer side beyond the softer side's "
          "mirror: zero for symmetric noise of any shape; nodules feel harder than the tissue, as the practice "
          "showed)"),
    Param("slide_damping", 1.0, low=1.0, high=10.0, unit="x",
          source="CHOSEN: how much more steadily the stylus is held while sliding against a felt push: a factor on "
          "the device hand's damping (its grip_damping input; 3 makes the relaxed 300 N/m, 8 N·s/m, 0.5 kg hold about "
          "critically damped, damping ratio 0.33 -> 1.0), its stiffness unchanged. Direction from motor control: "
          "people co-contract to stabilise an unstable interaction (Burdet, Osu, Franklin, Milner & Kawato 2001, "
          "Nature 414:446) and the hand's viscosity rises with muscle activation (Tsuji, Morasso, Goto & Ito 1995, "
          "Biol Cybern 72:475). Measured (trial loop, Table 1, one person of v5's means, 32 seeds, PHF+FF nodules "
          "found of 96): 1 -> 67, 3 -> 69, 6 -> 72 (PHF 85); tripling the stiffness with the damping did not help "
          "(8 seeds). 1: off"),
    Param("practice", "none", kind=str, choices=("none", "weights", "learn"),
          source="CITED: the behaviour (seed 003: a practice run with visible hard nodules before each test): the "
          "person presses on and around the nodules it sees and on plain tissue with the condition's feedback and "
          "learns per cue the excess a press near a nodule shows and the spread of plain presses "
          "(studyctl.participants.tissue_practice). weights: its press cues are then weighted as the ideal observer "
          "does (mean excess over variance, Green & Swets 1966; learnt with feedback, Atkins, Fiser & Jacobs 2001); "
          "learn: also a re-palpated spot is tested against the faintest nodule's learnt excess (CHOSEN); none: the "
          "practice is skipped"),
    Param("manual_practice", "none", kind=str, choices=("none", "transparent"), source=(
        "CITED: the behaviour (seed 002 §V: 'Before the manual palpation experiment, participants were asked to do a "
        "practice trial run palpating a transparent silicone phantom tissue with and without nodules inside') "
        "transparent: the engine runs a manual condition's familiarisation as a practice block for this person, "
        "who palpates the example phantom with the bare finger, its nodules seen (the scene's marks), and learns "
        "there what practice and thickness_prior say, as in a feedback condition's practice; the practice phantom "
        "is the trial's phantom (CHOSEN: the paper's transparent one is not described further); none: the "
        "familiarisation is skipped")),
    Param("practice_presses", 4, low=1, high=20, kind=int,
          source="CHOSEN: practice presses within half a press spacing of each visible nodule (and twice as many "
          "on plain tissue)"),
    Param("max_press_force_n", 3.0, low=0.1, high=20.0, unit="N", source="CHOSEN: below the Omni's 3.3 N"),
    Param("press_force_stop", 0.0, low=0.0, high=2.0,
          source="CHOSEN: (0 = off, the default) with a felt push and a cursor both showing the press, it also ends "
          "when the push reaches this fraction of the median push felt at the bottom of this trial's earlier "
          "presses, whichever of the two signals comes first (redundant signals: a race of two cues, Miller 1982); "
          "without it the press waits for the slowed cursor to reach the wanted depth"),
    Param("press_stall_stop", 0.0, low=0.0, high=1.0, source=(
        "CHOSEN: (0 = off, the default; 0.2 as the candidate, set before any run) with a cursor on screen, the "
        "press also ends once the cursor, "
        "in the tissue, has moved down less than this fraction of what the hand was commanded to move over the last "
        "press_stall_s: it visibly stalls (pseudo-haptic slowing read as resistance, Lecuyer et al. 2000; seed 003 "
        "2.4: resistance is felt when the cursor becomes slower than the user expects). 0.2 lies well below the "
        "cursor's slowing at plain tissue, R_n/R_o = 1/(f_n + 1) ~ 0.55 for the ~0.8 N bottom push tissue_time_split "
        "measured, "
        "and far above the 5-10 % speed-discrimination Weber fraction (McKee 1981; De Bruyn & Orban 1988), so such a "
        "stall is plainly seen; without it the press waits for the slowed cursor to reach the wanted depth")),
    Param("press_hand_stop", 0.0, low=0.0, high=5.0, source=(
        "CHOSEN: (0 = off, the default; 1.0 as the landing-rule candidate) with a cursor on screen, the press "
        "also ends once the hand itself (its position sense; pseudo-haptic slowing changes the cursor, not the hand) "
        "has gone down this multiple of the wanted depth since the cursor entered the visible tissue, instead of "
        "servoing the slowed cursor through its last millimetre (visual vs proprioceptive control, Lecuyer et al. "
        "2000). 1.0: the hand goes the depth it wants. First chosen was 1.8 = 1/0.55 (the cursor's slowing at plain "
        "tissue, 1/(f_n + 1) at the ~0.8 N bottom push, s34) to keep the cursor's depth, but the typical person's "
        "split showed that 1.8 and 1.4 never fire (the slowed cursor reaches depth first), so 1.0 was taken before "
        "any landing-rule run")),
    Param("press_hand_stop_push_n", 0.0, low=0.0, high=5.0, unit="N", source=(
        "CHOSEN: (0 = no gate, the default; 0.02 as the landing-rule candidate, set before any run) press_hand_stop "
        "ends a press only on a tick where the person feels a push of at least this through the device: where a "
        "rendered force holds the hand back (FF, PHF+FF) the cursor is still near depth when the hand has gone it, "
        "while with pseudo-haptics alone nothing holds the hand and the stop left the slowed cursor short (PHF "
        "sensitivity 27 -> 15 % at seed 2024 without the gate). 0.02 N is the bar at which this participant already "
        "counts a push as felt (bottom-push record); no cited stylus force detection threshold was found")),
    Param("press_stall_s", 0.1, low=0.02, high=1.0, unit="s",
          source="CHOSEN: how long the cursor must stay stalled (press_stall_stop) before the press ends: about the "
          "100 ms a change of a moving target's speed takes to be seen"),
    # ---- decision
    Param("baseline_radius_mm", 25.0, low=2.0, high=200.0, unit="mm",
          source="CHOSEN: a spot is compared with the tissue around it"),
    Param("baseline_height_mm", 0.0, low=0.0, high=100.0, unit="mm",
          source="CHOSEN: a spot is compared only with presses where the visible tissue is within this of its "
          "thickness (a thin layer over the table presses firmer; 0: any thickness)"),
    Param("thickness_prior", "none", kind=str, choices=("none", "learn"), source=(
        "CHOSEN: (the physics: Hayes et al. 1972, in studyctl.participants.tissue_rim) learn: from its plain practice "
        "presses the person learns how much firmer the tissue feels where it looks thinner (contrast on visible "
        "thickness, a line) and judges each test press against what that line expects there; the practice block "
        "runs even with practice: none, whose cue weights then stay untaught; none: off")),
    Param("rim_slope", "as_learnt", kind=str, choices=("as_learnt", "physics_sign"), source=(
        "CITED: the sign (a bonded thin layer over a rigid base indents less as it thins: Hayes et al. 1972, in "
        "studyctl.participants.tissue_rim) physics_sign: the thickness_prior line is fitted with its slope held to "
        "<= 0, so a person whose few practice presses show thinner tissue as softer or flat expects no thickness "
        "effect (no correction) instead of the opposite of the physics; as_learnt: the slope as the presses give "
        "it")),
    Param("cluster_radius_mm", 10.0, low=1.0, high=100.0, unit="mm", source="CHOSEN: a nodule's reach"),
    Param("z_threshold", 3.0, low=0.5, high=50.0,
          source="FITTED: confidence to report: a spot's averaged contrast in SDs of the press noise"),
    Param("report_fraction", 0.0, low=0.0, high=1.0,
          source="FITTED: a spot is reported only if it feels at least this fraction as stiff (contrast) as the "
          "clearest one: what a nodule feels like is known from the practice run with visible nodules"),
    Param("expect_spots", 0, low=0, high=20, kind=int,
          source="CHOSEN: how many nodules a person expects (seen in the practice run with visible nodules); a "
          "targeted searcher stops surveying once it has felt that many clear spots (0: it surveys everything)"),
    Param("stop_z", 8.0, low=1.0, high=1000.0,
          source="FITTED: how clear (SDs of the press noise) each expected spot must feel before the survey stops; "
          "very high for a systematic searcher who covers the whole surface anyway"),
    Param("stop_yield", 0.0, low=0.0, high=20.0,
          source="CHOSEN: a searcher who expects expect_spots nodules also ends its survey once the nodules it expects "
          "the rest of its planned survey to find fall below this many (0: off, only the count ends it early); 0.5: "
          "it stops once it believes finishing more likely to find nothing than something. Seed 003's detection time "
          "'was recorded until they thought they had found all the nodules' (§2.7); the expected yield of the area "
          "still unsearched is Bayesian search theory's (Stone 1975, Theory of Optimal Search)"),
    Param("stop_detect_belief", 0.8, low=0.05, high=0.99,
          source="CHOSEN: the chance a person believes a nodule under the area it has pressed would have felt clear; "
          "below 1 a nodule not yet felt may be one missed there, not only one in the area still unpressed"),
    Param("stop_min_presses", 10, low=5, high=500, kind=int,
          source="CHOSEN: survey presses a targeted searcher makes before it may end its survey: it first learns what "
          "the tissue around feels like (the noise its spots stand out of is estimated from these presses)"),
    Param("follow_up_z", 1.5, low=0.0, high=50.0,
          source="CHOSEN: survey presses this suspicious are re-palpated"),
    Param("follow_up_shrink", 0.5, low=0.05, high=1.0,
          source="CHOSEN: the nodule contrast a re-palpated spot is tested for, as a share of its survey contrast "
          "(the most suspicious survey presses overstate it)"),
    Param("follow_up_min", 2, low=1, high=9, kind=int,
          source="CHOSEN: presses a person makes at a suspicious spot before dismissing it"),
    Param("follow_up_count", 5, low=0, high=50, kind=int, source="CHOSEN: spots re-palpated at most"),
    Param("follow_up_spacing_mm", 4.0, low=0.5, high=20.0, unit="mm", source="CHOSEN: a 3 × 3 local grid"),
    Param("pinpoint_presses", 0, low=0, high=4, kind=int,
          source="CHOSEN: presses at the neighbours of a re-palpated spot once it is judged a nodule (its 3 x 3 "
          "grid's four side points), feeling around it to pinpoint it before it is reported, as seed 002's task "
          "asked (§IV.A: 'pinpoint the found nodule positions'); 0 = none: the spot is left once its test decides"),
    Param("max_reports", 6, low=1, high=100, kind=int, source="CHOSEN: nobody marks more spots"),
    Param("follow_up_error", 0.05, low=1e-4, high=0.5,
          source="CHOSEN: confidence to settle a re-palpated spot: Wald's SPRT error rates (α = β)"),
    Param("cutaneous_ratio", 0.354, low=0.01, high=10.0,
          source="CITED: Bergmann Tiest & Kappers 2009 (IEEE ToH 2:189): compliance Weber fraction 15 % by direct "
          "touch, more than trebled without the finger's surface-deformation cue; optimal cue combination then "
          "gives the skin cue σ = 1/√8 of the force/displacement cue's"),
    Param("search_weber", 0.15, low=0.01, high=1.0,
          source="CHOSEN: a search rate (spots found per time) this much higher is noticed; judgements of how "
          "long a minutes-long search took are coarser than the 8-10 % of force and speed"),
)
