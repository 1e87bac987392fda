"""Run or resume a participant's session against a study database: the functions the CLI (and
``studyctl simulate`` / ``studyctl demo``) call.

Example: a virtual participant's whole session, deterministic given the seed::

    from studyctl.store import StudyStore
    from studyctl.engine import run_session

    with StudyStore.open("study.db") as store:
        result = run_session(store, "BIP-4KX7Q", virtual=True, seed=7)
        print(result.to_frame())
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sqlalchemy import select

from studyctl.devices.emulation import emulated
from studyctl.engine.clock import Clock, PacedClock, RealClock, SimulatedClock
from studyctl.engine.factory import EntryPointFactory, PluginFactory, build_participant
from studyctl.engine.loop_rates import simulation_rates
from studyctl.engine.plan import SessionPlan, Step
from studyctl.engine.planning import plan_for_participant
from studyctl.engine.preflight import preflight
from studyctl.engine.seeding import answer_rng, person_traits, session_seed
from studyctl.engine.session import SessionResult, SessionRunner
from studyctl.engine.store_recorder import StoreRecorder, refuse_second_session
from studyctl.engine.ui import Script, ScriptedUI, SessionUI, VirtualUI
from studyctl.errors import NotFoundError, PopulationError, SessionError, UsageError
from studyctl.plugins.interfaces import Participant
from studyctl.protocol.stored_plan import Schedule
from studyctl.store import StudyStore
from studyctl.store.enrollment import study_protocol
from studyctl.store.lease import take_lease
from studyctl.store.models import Event, Session

ProgressFn = Callable[[int, int, Step], None]
# Another front end for the person (the participant view): gets the session's participant, UI and recorder
# before the first step and returns the pair to use instead (wrappers that mirror prompts and requests).
Frontend = Callable[[Participant, SessionUI, StoreRecorder], tuple[Participant, SessionUI]]


@dataclass
class _Setup:
    participant: Participant
    ui: SessionUI
    clock: Clock
    cleanup: Callable[[], None]


def _prepare(
    plan: SessionPlan,
    seed: int,
    *,
    virtual: bool,
    factory: PluginFactory,
    participant: Participant | None,
    ui: SessionUI | None,
    clock: Clock | None,
    script: Script | None,
    log: Callable[[str], None] | None,
    person_params: Mapping[str, Any] | None = None,
) -> _Setup:
    """Preflight, then the participant, prompts and clock: all before anything is written."""
    report = preflight(plan, factory, virtual=virtual,
                       person_participant=participant is None and script is None and ui is None)
    report.raise_if_missing()
    cleanup: Callable[[], None] = lambda: None  # noqa: E731
    if virtual:
        if participant is None:
            ref = plan.virtual_participant
            if not ref:
                raise SessionError(f"the protocol of study {plan.study!r} names no virtual participant "
                                   "(participants.virtual); run it with a person instead of --virtual")
            # a population's person (fixed params and drawn traits) over the protocol's params
            participant = build_participant(factory, ref["plugin"], {**ref.get("params", {}), **(person_params or {})})
        clock = clock or SimulatedClock()
        if ui is None:
            ui = VirtualUI(participant, lambda pos, n: answer_rng(seed, pos, n), clock=clock, log=log)
        return _Setup(participant, ui, clock, cleanup)
    if script is not None:
        from studyctl.engine.person import ScriptedParticipant

        participant = participant or ScriptedParticipant(script, log=log)
        ui = ui or ScriptedUI(script, log=log)
        return _Setup(participant, ui, clock or SimulatedClock(), cleanup)
    if plan.hardware_device is None and log is not None:
        log("note: the protocol names no hardware device; this session runs on the simulated device "
            f"{(plan.simulated_device or {}).get('plugin', '?')} (rehearsal)")
    if ui is None or participant is None:
        from studyctl.engine.person import TerminalParticipant
        from studyctl.engine.terminal import Terminal, TerminalUI

        term = Terminal()
        tui = TerminalUI(term)
        person = participant or factory.load("participant", "person")()
        if isinstance(person, TerminalParticipant):
            person.attach(term, tui)
        participant, ui = person, ui or tui
        cleanup = term.restore
    return _Setup(participant, ui, clock or RealClock(), cleanup)


def _launch(
    plan: SessionPlan,
    seed: int,
    virtual: bool,
    begin: Callable[[], StoreRecorder],
    *,
    participant: Participant | None,
    ui: SessionUI | None,
    clock: Clock | None,
    script: Script | str | Path | None,
    factory: PluginFactory | None,
    progress: ProgressFn | None,
    speed: float | None,
    log: Callable[[str], None] | None,
    frontend: Frontend | None,
    person_params: Mapping[str, Any] | None = None,
    rehearse: bool = False,
    servo: bool | None = None,
    calibrations: tuple[StudyStore, int] | None = None,
    lsl: bool = False,
) -> SessionResult:
    """Prepare everything, then ``begin()`` the stored session (create or reopen it) and run it.

    Plugins, terminal and clock are ready before ``begin`` writes anything: a failure leaves no half-started
    session, and the terminal is restored whatever happens. A rehearsal starts the emulator of the plan's
    hardware device first and stops it at the end, whatever happens.
    """
    if isinstance(script, (str, Path)):
        script = Script.load(script)
    factory = factory or EntryPointFactory()
    if plan.hardware_device and not virtual and not rehearse:  # a missing SDK: one error before anything is written
        check = getattr(factory.load("device", plan.hardware_device["plugin"]), "check_installed", None)
        if callable(check):
            check()
    if lsl:  # before anything is written: a missing extra is a usage error, not a half-started session
        from studyctl.devices.lsl import load_pylsl  # noqa: PLC0415

        load_pylsl()
    setup = _prepare(plan, seed, virtual=virtual, factory=factory, participant=participant, ui=ui,
                     clock=clock or _paced(speed), script=script, log=log, person_params=person_params)
    rec = None
    try:
        with contextlib.ExitStack() as stack:
            device_ref = None
            if rehearse and plan.hardware_device:
                # a virtual participant acts on the emulated hardware: its hand goes into the emulator's world
                device_ref = stack.enter_context(emulated(plan.hardware_device, world=virtual))
                if log is not None:
                    log(f"rehearsal: device {device_ref['plugin']} is emulated "
                        f"({', '.join(f'{k}={v}' for k, v in sorted(device_ref['params'].items()))})"
                        + (f"; virtual participant {(plan.virtual_participant or {}).get('plugin')} acts on it"
                           if virtual else ""))
            elif rehearse and log is not None:
                log("rehearsal: the protocol names no hardware device; trials run on the simulated device "
                    f"{(plan.simulated_device or {}).get('plugin', '?')}")
            calibration = None
            if calibrations is not None and plan.hardware_device and (rehearse or not virtual):
                from studyctl.engine.device_check import latest_calibration  # noqa: PLC0415

                base = device_ref or dict(plan.hardware_device)
                calibration = latest_calibration(calibrations[0], calibrations[1], base["plugin"], emulated=rehearse)
                if calibration is not None:  # the newest zero/calibration of this device in the study
                    device_ref = {**base, "params": {**dict(base.get("params") or {}), **calibration.params}}
            rec = begin()
            if rec.lease is not None:
                rec.lease.start_heartbeat()
            if lsl:
                from studyctl.devices.lsl import LslRecorder, LslStreams  # noqa: PLC0415

                rec = LslRecorder(rec, LslStreams(f"studyctl:{plan.study}:{rec.state().session_id}"))
                stack.callback(time.sleep, 0.5)  # let recorders fetch the last samples before the outlets close
            if calibration is not None:
                rec.event("device_calibration", {"calibration_id": calibration.id, "device": calibration.device,
                                                 "created_at": calibration.created_at, "params": calibration.params},
                          t=rec.state().last_t)
            if frontend is not None:
                setup.participant, setup.ui = frontend(setup.participant, setup.ui, rec)
            virtual_ref = None
            if virtual and participant is None and plan.virtual_participant:  # rebuilt in the servo process
                ref = plan.virtual_participant
                virtual_ref = {"plugin": ref["plugin"], "params": {**ref.get("params", {}), **(person_params or {})}}
            runner = SessionRunner(rec, ui=setup.ui, participant=setup.participant, clock=setup.clock,
                                   factory=factory, virtual=rec.state().virtual, progress=progress,
                                   device_ref=device_ref, servo=servo, virtual_ref=virtual_ref)
            return runner.run()
    finally:
        try:
            if rec is not None:
                rec.close()
        finally:
            setup.cleanup()


def run_session(
    store: StudyStore,
    participant_code: str,
    *,
    study: str | None = None,
    virtual: bool = True,
    seed: int | None = None,
    participant: Participant | None = None,
    ui: SessionUI | None = None,
    clock: Clock | None = None,
    script: Script | str | Path | None = None,
    factory: PluginFactory | None = None,
    progress: ProgressFn | None = None,
    site: str | None = None,
    speed: float | None = None,
    log: Callable[[str], None] | None = None,
    frontend: Frontend | None = None,
    sim_rate_hz: float | None = None,
    population: Any | None = None,
    traits: Mapping[str, float] | None = None,
    rehearse: bool = False,
    servo: bool | None = None,
    lsl: bool = False,
) -> SessionResult:
    """Run an enrolled participant's whole session, from instructions to the end-of-study questionnaire.

    Parameters
    ----------
    store
        The open study database.
    participant_code
        The participant's pseudonymous code (as printed by ``studyctl enroll``).
    study
        Study name when the database holds several.
    virtual
        True: the protocol's virtual participant acts through the simulated device on a simulated clock
        (as fast as the computation allows). False: a person (terminal, or ``script``) on the hardware
        device named by the protocol (the simulated device when it names none).
    seed
        Session seed; every trial's and answer's random stream derives from it and the plan position, so a
        virtual session is reproducible and a resumed one continues identically. Default: derived from
        the study seed and the participant code.
    participant, ui, clock
        Override the participant plugin instance, the prompts and the clock (tests, embedding).
    script
        Scripted answers (a :class:`~studyctl.engine.ui.Script` or a YAML/JSON file) for a person run
        without a terminal (rehearsals, tests).
    factory
        Plugin source (default: installed entry points).
    progress
        Called after every step with (steps done, steps in plan, step).
    frontend
        Called once with (participant, ui, recorder) before the first step; returns the participant and UI
        to use instead (e.g. :meth:`studyctl.view.ParticipantView.attach`, the participant's screen).
    speed
        Virtual or scripted runs only: hold the simulated clock to at most this many times real time
        (to watch a run); results are identical to an unpaced run.
    sim_rate_hz
        Virtual sessions only: run the feedback loop of conditions whose controller allows it
        (``Controller.rate_adjustable``) at most this fast, instead of the controller's rate (1 kHz for the
        tissue and needle controllers). The simulated device still integrates its physics at its own rate; what this
        changes in the outcomes is measured by ``studyctl bench simrate``. The rates go into the stored plan
        (a resume keeps them) and every trial records the rate it ran at. None: the protocol's rates.
    population
        Virtual sessions only: a :class:`~studyctl.populations.TraitPopulation` for the protocol's participant
        kind. The person's traits are the session seed's person
        (:func:`~studyctl.engine.seeding.person_traits`, stratum-aware) unless ``traits`` gives them, and
        reach the participant as constructor params (fixed ones, then traits, over the protocol's params).
        The population's name, version, sha256 and the person's traits are stored as a ``population`` event in
        the transaction that starts the session; a resume rebuilds the same person from it.

    servo
        Hardware trials run in the servo process (None, the default) or, with False, in this process (for
        comparison; a 1 kHz loop beside prompts and the store keeps worse time, see ``studyctl bench servo``).
    lsl
        Also publish the session's events (markers) and samples to the Lab Streaming Layer
        (:mod:`studyctl.devices.lsl`; extra ``lsl``).
    rehearse
        A rehearsal: every hardware device is replaced by its emulator (started here in its own process and
        stopped at the end); the session is recorded in the study marked ``rehearsal`` and analysis leaves it
        out. The participant's status does not change and earlier rehearsals do not count as taking part.
        With ``virtual`` the virtual participant acts on the emulated hardware instead of the simulated device:
        its hand is in the emulator's world (:mod:`studyctl.devices.world`), everything else goes through the
        real adapter, the servo process and the emulator, in real time. Its person is drawn from ``population``
        (the CLI passes the protocol's shipped one, as ``simulate`` does; without one, the participant's defaults).

    Returns
    -------
    SessionResult
        How the session ended (``status == "completed"`` unless it raised).

    Raises
    ------
    NotFoundError
        Unknown participant code.
    SessionError
        The participant already has a finished or unfinished session, preflight found a missing plugin,
        or a device failed (the session is then resumable with :func:`resume_session`).
    SessionInterrupted
        Ctrl-C; the session is resumable.
    """
    target = store.get_study(study)
    try:
        person = store.get_participant(target.id, participant_code)
    except NotFoundError:
        codes = [p.code for p in store.list_participants(target.id)]
        hint = f"; enrolled codes: {', '.join(codes[:10])}{' …' if len(codes) > 10 else ''}" if codes else ""
        raise NotFoundError(f"no participant with code {participant_code!r} in study {target.name!r}"
                            f"{hint}. Enroll one with `studyctl enroll`") from None
    if person.status == "withdrawn":
        raise SessionError(f"participant {participant_code} has withdrawn; their sessions cannot be run")
    # early, readable refusal; StoreRecorder.create checks again inside the transaction that starts the session
    if not rehearse:  # rehearsals are not taking part: any number of them, before or after the real session
        with store.reading() as s:
            refuse_second_session(store, s, person)
    if not person.schedule:
        raise SessionError(f"participant {participant_code} has no stored schedule; enroll with `studyctl enroll`")
    protocol = study_protocol(target)
    plan = plan_for_participant(protocol, Schedule.from_json(person.schedule))
    if sim_rate_hz is not None:
        if not virtual:
            raise SessionError("a reduced simulation loop rate is for virtual participants only; a person's "
                               "session runs at the protocol's rates")
        plan = plan.with_condition_rates(simulation_rates(plan, factory or EntryPointFactory(), sim_rate_hz))
    seed = session_seed(int(target.seed), participant_code) if seed is None else int(seed)
    record = person_params = None
    if population is not None:
        if not virtual:
            raise SessionError("a population describes virtual participants; a person's session takes none")
        plugin = (plan.virtual_participant or {}).get("plugin")
        if plugin != population.participant:
            raise PopulationError(f"population {population.path or population.name} is for participant "
                                  f"{population.participant!r}, but study {target.name!r} simulates {plugin!r}; "
                                  f"give a population written for {plugin}")
        if traits is None:
            traits = person_traits(population, seed, person.stratum)
        record = population.record(traits, person.stratum)
        person_params = population.params(traits)
    return _launch(plan, seed, virtual,
                   lambda: StoreRecorder.create(store, person.id, plan, seed=seed, virtual=virtual, site=site,
                                                population=record, lease=True, rehearsal=rehearse),
                   participant=participant, ui=ui, clock=clock, script=script, factory=factory, progress=progress,
                   speed=speed, log=log, frontend=frontend, person_params=person_params, rehearse=rehearse,
                   servo=servo, calibrations=(store, int(target.id)), lsl=lsl)


def _session_head(store: StudyStore, session_id: int) -> dict:
    with store.reading() as s:
        payload = s.scalar(select(Event.payload).where(Event.session_id == session_id, Event.kind == "session_plan")
                           .order_by(Event.seq).limit(1))
    return dict(payload or {})


def session_is_virtual(store: StudyStore, session_id: int) -> bool:
    """Whether a stored session is run by a virtual participant (False for people, or an unknown session)."""
    return bool(_session_head(store, session_id).get("virtual", False))


def session_is_rehearsal(store: StudyStore, session_id: int) -> bool:
    """Whether a stored session is a rehearsal on emulated hardware (recorded, never analysed)."""
    return bool(_session_head(store, session_id).get("rehearsal", False))


def resume_session(
    store: StudyStore,
    session_id: int,
    *,
    participant: Participant | None = None,
    ui: SessionUI | None = None,
    clock: Clock | None = None,
    script: Script | str | Path | None = None,
    factory: PluginFactory | None = None,
    progress: ProgressFn | None = None,
    speed: float | None = None,
    log: Callable[[str], None] | None = None,
    frontend: Frontend | None = None,
    take_over: bool = False,
    lsl: bool = False,
) -> SessionResult:
    """Continue an interrupted session from its stored plan (see :func:`run_session` for parameters).

    Completed steps, trials and answers are kept; a trial interrupted mid-way is handled by the protocol's
    policy (``repeat`` it, or mark it invalid and append a replacement); the resume is audited. The session
    keeps its mode (virtual or person) and seed.

    The session's lease is taken first (one writer per session): while another process runs the session
    this raises :class:`SessionError` naming its pid, host and start. A lease left behind (its process
    provably gone, or on another host with a stale heartbeat) is taken over, and audited, only with
    ``take_over``; without it the error says who holds it, since when, and to use ``--take-over``.
    """
    store.get_session(session_id)  # NotFoundError first
    with store.in_transaction() as tx:
        sess = tx.get(Session, session_id)
        if sess.status == "completed":
            raise SessionError(f"session {session_id} is already complete; nothing to resume")
        if sess.status == "aborted":
            raise SessionError(f"session {session_id} was aborted; it cannot be resumed")
        lease = take_lease(store.db, tx, session_id, take_over=take_over)
    try:
        rec = StoreRecorder.load(store, session_id)
    except BaseException:
        lease.release()
        raise
    rec.lease = lease
    state = rec.state()
    stored = stored_population(store, session_id) if state.virtual else None
    person_params = {**stored.get("fixed", {}), **stored.get("traits", {})} if stored else None
    study_id = store.get_participant_by_id(rec.participant_id).study_id
    try:
        return _launch(state.plan, state.seed, state.virtual, lambda: rec, participant=participant, ui=ui,
                       clock=clock, script=script, factory=factory, progress=progress, speed=speed, log=log,
                       frontend=frontend, person_params=person_params, rehearse=state.rehearsal,
                       calibrations=(store, int(study_id)), lsl=lsl)
    finally:
        rec.close()


def stored_population(store: StudyStore, session_id: int) -> dict[str, Any] | None:
    """The ``population`` event of a session (which population, this person's traits), or None."""
    with store.reading() as s:
        payload = s.scalar(select(Event.payload).where(Event.session_id == session_id, Event.kind == "population")
                           .order_by(Event.seq).limit(1))
    return dict(payload) if payload else None


def _paced(speed: float | None) -> Clock | None:
    if speed is None:
        return None
    if not (0 < speed < float("inf")):
        raise UsageError(f"--speed must be a positive number (times real time, e.g. 1 or 10), got {speed}")
    return PacedClock(speed)
