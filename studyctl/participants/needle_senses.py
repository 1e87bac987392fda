"""What the virtual needle operator does with what it senses: images, forces, and what it has learnt to trust.

:class:`OperatorSenses` is the perceiving half of :class:`~studyctl.participants.needle_operator.VirtualNeedleOperator`
(a mixin over the same trial state): it reads a CT frame or the live view into its position sense and its
plan, yields to a felt guidance push and judges the channel's stiffness from force over sideways travel,
and feeds the axial force to the cue detector. The raw sensing (position sense, force split, cue detector)
is in :mod:`~studyctl.participants.needle_perception`; the decisions are the operator's phase handlers.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from studyctl.participants.ct_reader import CTReading, read_ct
from studyctl.participants.needle_params import OperatorParams, Vec
from studyctl.participants.needle_perception import Plan, feel_force
from studyctl.participants.needle_trial import Line, MinJerk, Phase, TrialState, learn_trust, norm

__all__ = ["CLEAR_CUE", "OperatorSenses"]

# with ``cue_by_feel``, the key of trust_cue that holds trust in a clear axial cue (scenario labels key it otherwise)
CLEAR_CUE = "felt:clear"


class OperatorSenses:
    """Perception and trust of the needle operator (mixed into :class:`VirtualNeedleOperator`)."""

    p: OperatorParams
    trust_cue: dict[str, float]
    trust_guide: dict[str, float]
    wall_k: dict[str, float]
    clear_cue_in: set[str]

    @property
    def _st(self) -> TrialState:  # provided by the operator
        raise NotImplementedError

    def _trusts_cue(self) -> bool:
        label = self._st.info.condition
        if self.p.cue_by_feel >= 0.5:
            # trust belongs to the clear cue as felt, and a scenario is trusted once it has felt that cue there
            return label in self.clear_cue_in and self.trust_cue.get(CLEAR_CUE, 0.0) >= 0.5
        return self.trust_cue.get(label, 0.0) >= 0.5

    def _learn_from_cue(self, confirmed: bool) -> None:
        """A felt cue judged against an image: was it the tumour? (``confirmed``: the tip was at it).

        Off ``cue_by_feel``, trust is kept per scenario label, whatever the cue felt like. On, only a clear cue
        (``cue_clear_ratio``) teaches, and what it teaches is trust in that cue wherever it is felt; a faint one
        teaches nothing, as it could not be told from the liver's own bumps."""
        st, p = self._st, self.p
        if p.cue_by_feel < 0.5:
            learn_trust(self.trust_cue, st.info.condition, p.cue_trust_rate, confirmed)
        elif self._felt_clear_cue():
            learn_trust(self.trust_cue, CLEAR_CUE, p.cue_trust_rate, confirmed)

    def _felt_clear_cue(self) -> bool:
        """Was the cue just felt a clear one (``cue_by_feel``)? If so it remembers that this scenario gives it."""
        st, p = self._st, self.p
        if p.cue_by_feel < 0.5 or st.cue.clearness() < p.cue_clear_ratio:
            return False
        self.clear_cue_in.add(st.info.condition)
        return True

    def _trusts_guide(self) -> bool:
        # Kept per scenario label on purpose, unlike cue_by_feel: EG's and ESG's channels are not the same stimulus
        # (Table 1: spring k_p 1000 N/m in both, damper k_d 70 vs 50 N·s/m), and a 40 % step in viscosity is above
        # the Weber fractions people show for it (19-34 %, Jones, Hunter & Lafontaine 1997, Perception 26:1571),
        # so trust in one channel need not carry to the other. It costs little: the probe of each scenario's
        # first trial teaches the trust within that trial (session 35).
        return self.trust_guide.get(self._st.info.condition, 0.0) >= 0.5

    def _probing_channel(self) -> bool:
        """Can a lateral push growing now tell it how stiff the channel is?

        People judge stiffness from the force against the displacement they make (Jones & Hunter 1990, Exp Brain
        Res 79:150), by actively pressing (Srinivasan & LaMotte 1995, J Neurophysiol 73:88); a force that grows
        with speed is viscosity, a different percept (Jones & Hunter 1993, Exp Brain Res 94:343). So only moves
        at a pace of its own, set apart from its reaching speed, count: advancing in tissue, where a stray off
        the line grows at its insertion pace, and its sideways probe (``probe_mm`` out and back,
        :data:`~studyctl.participants.needle_operator.PROBE_S` each way), where it presses into the channel
        slowly on purpose. Not while reaching onto the incision: that goes at its free-reach speed
        (``approach_speed_ratio``), where the channel's damper pushes back whatever the stiffness (a probe that
        came back at that speed read BL's 100 N/m spring as a 966 N/m wall at a ratio of 3.0: session 29)."""
        st = self._st
        if st.phase is Phase.INSERT:
            return True
        return st.phase is Phase.APPROACH and st.probing and isinstance(st.move, MinJerk)

    def _channel_speed(self) -> float:
        """Advance speed inside a guidance channel it trusts.

        Its pace through tissue is set by the lateral accuracy it must keep by itself: its hand's slips grow with
        speed (signal-dependent motor noise, :meth:`_command`). A channel of stiffness k, felt against its own arm
        stiffness k_arm, lets a hand slip move the tip only k_arm/(k_arm + k) as far, so the same tip accuracy
        allows (1 + k/k_arm) times its speed, but never more than its free-reach speed (``approach_speed_ratio``).
        """
        st, p = self._st, self.p
        k = self.wall_k.get(st.info.condition, 0.0)
        return st.v_ins * min(p.approach_speed_ratio, 1.0 + k / p.arm_stiffness_n_per_m)

    def _belief(self, percept: Mapping[str, Any]) -> Vec:
        st = self._st
        return st.sense.belief(percept, st.last_cmd)

    def _take_image(self, frame: Mapping[str, Any], percept: Mapping[str, Any]) -> CTReading:
        reading = read_ct(frame, self._st.axis)
        self._use_reading(reading, percept)
        return reading

    def _look_live(self, t: float, frame: Mapping[str, Any], percept: Mapping[str, Any]) -> None:
        """A look at the live view. With ``realtime_view_delay_s`` it is acted on only that long after the look,
        against where it feels its hand by then (visual feedback of a moving hand steers it only after 117-200 ms:
        Saunders & Knill 2005), so a tip seen while moving is taken to be where it was; 0 acts on it at once."""
        st, delay = self._st, self.p.realtime_view_delay_s
        if delay <= 0.0:
            self._take_image(frame, percept)
            return
        st.pending_views.append((t + delay, read_ct(frame, st.axis)))

    def _act_on_looks(self, t: float, percept: Mapping[str, Any]) -> None:
        """Act on the delayed looks whose time has come (``realtime_view_delay_s``), oldest first."""
        pending = self._st.pending_views
        while pending and pending[0][0] <= t:
            self._use_reading(pending.popleft()[1], percept)

    def _use_reading(self, reading: CTReading, percept: Mapping[str, Any]) -> None:
        """What an image showed, taken into its position sense (the tip) and its plan (tumour and marker)."""
        st = self._st
        if reading.tip_mm is not None:
            keep = self._sideways_tolerance(percept)
            old = st.sense.see_tip(reading.tip_mm, st.sense.felt(percept, st.last_cmd), 0.3, axis=st.axis,
                                   keep_lat_mm=keep)
            c, r = st.sense.corr, st.ref
            # the belief moved, the hand did not: keep the set-point where it is
            st.ref = (r[0] + c[0] - old[0], r[1] + c[1] - old[1], r[2] + c[2] - old[2])
            st.prev_ref = st.ref
            st.blind_at = None
        elif st.plan is not None:  # a check that showed no tip: where the hand was (see _scan_can_show_tip)
            st.blind_at = st.sense.felt(percept, st.last_cmd)
        if st.plan is None and reading.tumour_mm is not None and reading.marker_mm is not None:
            self._make_plan(reading.tumour_mm, reading.marker_mm)

    def _sideways_tolerance(self, percept: Mapping[str, Any]) -> float:
        """How far off sideways a look at the live view may show the tip before it re-aims (``rt_tolerance_mm``).

        Only in the first, ballistic part of the advance: advancing along the plan and still more than
        ``margin_mm`` short of where it believes the tumour is. Closer in it is homing in and corrects every seen
        error, as aiming does in the two-component model (an initial impulse, then a homing phase under visual
        control that sets the endpoint's accuracy: Elliott et al. 2010, Psychol Bull 136:1023). With
        ``rt_tolerance_reach`` the reach onto the incision belongs to that first part too (it need not line up
        exactly before entering when it can steer on the way). Stopped, judging, correcting, and on a requested
        scan it takes all of the error.
        """
        st, p = self._st, self.p
        if p.rt_tolerance_mm <= 0.0 or not st.realtime:
            return 0.0
        if st.phase is Phase.APPROACH and p.rt_tolerance_reach >= 0.5:
            return p.rt_tolerance_mm
        if st.phase is not Phase.INSERT or st.stop_reason != "depth":
            return 0.0
        pl = st.need_plan()
        if pl.depth(self._belief(percept)) >= pl.length - p.margin_mm:
            return 0.0
        return p.rt_tolerance_mm

    def _make_plan(self, t: Vec, m: Vec) -> None:
        st = self._st
        d = (t[0] - m[0], t[1] - m[1], t[2] - m[2])
        length = norm(d)
        u = (d[0] / length, d[1] / length, d[2] / length)
        # the pen is pointed along the plan with an orientation error
        z = st.noise()
        err = math.radians(self.p.orientation_sd_deg)
        a = (u[0] + err * z[0], u[1] + err * z[1], u[2] + err * z[2])
        n = norm(a)
        st.axis = (a[0] / n, a[1] / n, a[2] / n)
        pre = self.p.preentry_mm
        st.plan = Plan(t, m, u, length, (m[0] - pre * u[0], m[1] - pre * u[1], m[2] - pre * u[2]))

    def _perceive(self, t: float, percept: Mapping[str, Any]) -> None:
        """Forces on the hand: follow a felt guidance push, and watch the axial force for a cue."""
        st, p = self._st, self.p
        felt = feel_force(percept, st.axis, p.force_noise_n, st.noise()) if "fx_n" in percept else None
        if felt is None:
            return
        cond = st.info.condition
        if st.button >= 0.5 and felt.radial_n > p.radial_threshold_n:
            # a felt lateral push: yield to it, and trust that it keeps the tip near the path
            g = p.follow_gain_mm_per_ns * st.dt
            if st.realtime:  # the live view shows the tip: the push counts by its weight (1, the default: in full)
                g *= p.realtime_follow_weight
            r, (rx, ry, rz) = st.ref, felt.radial
            st.ref = (r[0] + g * rx, r[1] + g * ry, r[2] + g * rz)
            st.record["radial_felt_s"] += st.dt
            hand = st.sense.felt(percept, st.last_cmd)
            if st.felt_radial_s == 0.0:
                st.radial_onset = hand  # where the lateral push was first felt
                st.radial_onset_n = felt.radial_n
            st.felt_radial_s += st.dt
            if st.felt_radial_s > 0.2:
                st.sense.sig_lat = min(st.sense.sig_lat, p.finish_mm)
            # how far the hand went sideways while the push grew from just felt to wall_n: a short way is a stiff
            # wall (EG/ESG, 10x the BL spring), a long way a soft pull; stiffness is judged from force and travel
            o, a = st.radial_onset, st.axis
            dx, dy, dz = hand[0] - o[0], hand[1] - o[1], hand[2] - o[2]
            along = dx * a[0] + dy * a[1] + dz * a[2]
            travel = math.sqrt(max(0.0, dx * dx + dy * dy + dz * dz - along * along))
            if felt.radial_n > p.wall_n and travel <= p.wall_travel_mm and st.radial_onset_n < p.wall_n \
                    and self._probing_channel() and not st.record["wall"]:
                # the channel, felt while lining up over the incision or in tissue (once a trial), as a push that grew
                # from just noticeable (a push already strong when first felt says nothing of stiffness): it learns
                # to rely on it, and how stiff it is (force rise over the sideways travel; its felt position
                # resolves no finer than 0.05 mm)
                st.record["wall"] = True
                learn_trust(self.trust_guide, cond, p.guide_trust_rate, True)
                k_felt = 1000.0 * (felt.radial_n - st.radial_onset_n) / max(travel, 0.05)
                k_old = self.wall_k.get(cond)
                self.wall_k[cond] = k_felt if k_old is None else k_old + p.guide_trust_rate * (k_felt - k_old)
                if self._trusts_guide() and not st.guided and isinstance(st.move, Line) and st.stop_reason == "depth":
                    st.guided = True  # a firm channel, felt now: it need not fear lateral slips for the rest
                    st.move.v = max(st.move.v, self._channel_speed())
                    st.cue.expect_change()
        else:
            st.felt_radial_s = 0.0
        if st.button >= 0.5 and self._trusts_guide():
            # inside a channel it has felt to be firm (the guidance acts from before the incision on), it takes
            # the tip to be on the path laterally: below both its criteria, so it neither stops to check the line
            # on the way (recheck_mm) nor needs a scan to confirm it (finish_mm)
            st.sense.sig_lat = min(st.sense.sig_lat, 0.9 * min(p.finish_mm, p.recheck_mm))
        # axial cue: a rise above the running baseline while advancing deep in the liver
        mv = st.move
        if st.phase is Phase.INSERT and st.plan is not None and st.button >= 0.5 and isinstance(mv, Line):
            mv.moving_s += st.dt
            depth = st.plan.depth(self._belief(percept))
            if st.cue.update(felt.axial, depth, 0.5 * st.plan.length, mv.moving_s, st.dt,
                             p.force_threshold_n, p.force_weber):
                st.record["cue"] = True
                st.react_until = t + p.reaction_s
