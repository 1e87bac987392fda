"""The contracts every controller, device, scene and participant plugin implements.

One trial tick, as :func:`studyctl.engine.trial_loop.run_trial` drives it::

    action  = participant.act(t, percept)          # a virtual participant decides; a person's
                                                   #   hardware inputs arrive through the device
    device.apply_input(action.inputs)              # simulated devices only (no-op on hardware)
    obs     = device.read(t)                       # sensors; a simulated device asks the scene
    command = controller.step(obs)                 # the feedback algorithm
    device.write(safety.filter(command, t, obs))   # the safety layer stands between the two
    percept = device.feedback()                    # what the actuators deliver to the hand/eye

Channels are named floats (``Mapping[str, float]``) so that logging, safety limits and export treat
every plugin alike. Units go in the channel name suffix (``_n``, ``_mm``, ``_kpa``, ``_psi``, ``_pct``).

Construction (what :mod:`studyctl.engine.factory` and :mod:`studyctl.plugins.registry` call):
``SceneClass.build(spec, placement, needs, rng)``, ``ControllerClass(params, scene)``,
``DeviceClass(params=..., scene=..., rng=...)`` and ``ParticipantClass(params=...)``; plugins validate
their params in the constructor and raise :class:`studyctl.errors.ModelParameterError`
(:func:`studyctl.plugins.params.validate_params` does it for a declared spec).

Additions after the first version (all optional, with defaults, so older plugins keep working):
``Observation.sample_t`` and ``Observation.faults`` (sensor age and device-detected problems, read by
the safety layer's watchdog), ``Scene.public()`` (what a participant may know, e.g. the grid),
``Controller.outputs``, ``Controller.rate_adjustable``, ``Controller.set_loop_rate``,
``Participant.memory``/``recall``, and default constructors for ``Device`` and ``Participant``.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from studyctl.errors import NotSupportedError
from studyctl.suggest import named

Channels = Mapping[str, float]


@dataclass(frozen=True)
class ChannelLimit:
    """Allowed range of one output channel and the value that is safe when anything goes wrong."""

    name: str
    low: float
    high: float
    safe: float = 0.0
    max_rate_per_s: float | None = None  # rate-of-change limit, units per second
    unit: str = ""


@dataclass(frozen=True)
class DeviceLimits:
    """Everything the safety layer needs to know about a device."""

    outputs: tuple[ChannelLimit, ...]
    max_force_n: float | None = None  # Euclidean bound on (fx_n, fy_n, fz_n) when the device renders force
    sensor_stale_s: float = 0.1  # a sensor older than this puts the device in its safe state
    ramp_up_s: float = 0.0  # outputs are scaled 0→1 over this time after enable

    def channel(self, name: str) -> ChannelLimit:
        return named(self.outputs, name, what="output channel", plural="channels", key="name")

    def safe_command(self) -> dict[str, float]:
        return {c.name: c.safe for c in self.outputs}


@dataclass(frozen=True)
class Observation:
    """What a controller sees at one tick: trial time in seconds and named sensor channels.

    ``sample_t`` is the trial time at which the newest sensor sample was actually taken (hardware: when
    its packet arrived); None means "now" (simulated devices). The safety layer commands the safe state
    when ``t - sample_t`` exceeds the device's ``sensor_stale_s``. ``faults`` lists problems the device
    detected while reading (e.g. an ADC value outside its range); any fault also puts the device in its
    safe state for that tick.
    """

    t: float
    values: Channels
    sample_t: float | None = None
    faults: tuple[str, ...] = ()

    # Built every tick (1 kHz): the generated frozen __init__ pays an object.__setattr__ call per field (2.8 vs
    # 1.2 us measured); writing the instance dict is the same result and it stays frozen for everyone else.
    def __init__(self, t: float, values: Channels, sample_t: float | None = None,
                 faults: tuple[str, ...] = ()) -> None:
        d = self.__dict__
        d["t"] = t
        d["values"] = values
        d["sample_t"] = sample_t
        d["faults"] = faults


@dataclass(frozen=True)
class Request:
    """Something a participant asks for during a trial: ``scan``, ``report`` (with a payload), ``finish``."""

    kind: str
    payload: Mapping[str, Any] = field(default_factory=dict)

    def __init__(self, kind: str, payload: Mapping[str, Any] | None = None) -> None:  # see Observation
        d = self.__dict__
        d["kind"] = kind
        d["payload"] = {} if payload is None else payload


@dataclass(frozen=True)
class Action:
    """A participant's output at one tick: device inputs (simulated devices) and requests."""

    inputs: Channels = field(default_factory=dict)
    requests: tuple[Request, ...] = ()

    def __init__(self, inputs: Channels | None = None, requests: tuple[Request, ...] = ()) -> None:  # see Observation
        d = self.__dict__
        d["inputs"] = {} if inputs is None else inputs
        d["requests"] = requests


@dataclass(frozen=True)
class TrialInfo:
    """What a participant may know about a trial: never the hidden truth (tumour sites)."""

    condition: str
    time_limit_s: float
    rate_hz: float
    visual: str = "none"  # "none", "on_request" (scans counted), "realtime"
    public: Mapping[str, Any] = field(default_factory=dict)  # grid size, nodule count, instructions …


class Scene(ABC):
    """A tissue or phantom model. ``build`` constructs only the parts a trial needs."""

    name: ClassVar[str]

    @classmethod
    @abstractmethod
    def build(
        cls, spec: Mapping[str, Any], placement: Mapping[str, Any], needs: frozenset[str], rng: np.random.Generator
    ) -> Scene:
        """Build from the protocol's scene spec and this trial's stored placement.

        ``needs`` names the parts the condition's controller and visual channel use; parts not named
        must not be built.
        """

    @abstractmethod
    def sense(self, inputs: Channels) -> dict[str, float]:
        """Sensor channels a simulated device reads for the given device inputs (probe pose …)."""

    def view(self, inputs: Channels) -> Mapping[str, Any] | None:
        """A visual frame (CT slice, cursor and surface) for the given inputs, or None if no view."""
        return None

    def truth(self) -> Mapping[str, Any]:
        """Hidden ground truth for metrics (tumour sites); never handed to a participant."""
        return {}

    def public(self) -> Mapping[str, Any]:
        """What a participant may know about the scene (grid size, operating area); goes to ``TrialInfo.public``."""
        return {}


class Controller(ABC):
    """A feedback algorithm: observation in, device command out, at ``rate_hz``."""

    name: ClassVar[str]
    rate_hz: float = 50.0
    outputs: ClassVar[tuple[str, ...]] = ()  # channels this controller commands (informational)
    #: True when the controller's models integrate with the measured time step between observations, so a
    #: simulated session may run its loop below ``rate_hz`` (``run_session(sim_rate_hz=…)``; the simulated
    #: device still integrates its physics at its own rate). False: the loop always runs at ``rate_hz``
    #: (e.g. a model whose time step or damping rules are tied to its rate).
    rate_adjustable: ClassVar[bool] = False

    def __init__(self, params: Mapping[str, Any], scene: Scene | None = None) -> None:
        self.params = dict(params)
        self.scene = scene

    @classmethod
    def needs(cls, params: Mapping[str, Any]) -> frozenset[str]:
        """Scene parts and models this controller needs with these parameters."""
        return frozenset()

    def set_loop_rate(self, rate_hz: float) -> None:  # noqa: B027 - optional hook, a no-op by default
        """The rate the trial loop will call :meth:`step` at (called before :meth:`reset`, every trial).

        Below ``rate_hz`` only in a simulated session at a reduced loop rate (``rate_adjustable``). A controller
        whose state advances a fixed amount per step (a cross-fade, a window of samples) scales it here, so its
        behaviour stays the same in seconds. The default keeps nothing."""

    @abstractmethod
    def reset(self) -> None:
        """Forget all state (filters, puncture flags) before a trial."""

    @abstractmethod
    def step(self, obs: Observation) -> dict[str, float]:
        """One update: the command for each output channel."""


class Device(ABC):
    """A device: hardware adapter or simulation. ``limits`` feed the safety layer."""

    name: ClassVar[str]
    limits: DeviceLimits
    simulated: ClassVar[bool] = True

    def __init__(
        self,
        params: Mapping[str, Any] | None = None,
        scene: Scene | None = None,
        rng: np.random.Generator | None = None,
    ) -> None:
        self.params = dict(params or {})
        self.scene = scene
        self.rng = rng

    @abstractmethod
    def open(self) -> None: ...

    @abstractmethod
    def read(self, t: float) -> Observation: ...

    @abstractmethod
    def write(self, command: Channels) -> None: ...

    @abstractmethod
    def close(self) -> None:
        """Command the safe state and release the device. Must be safe to call twice."""

    def apply_input(self, inputs: Channels) -> None:
        """Simulated devices take a virtual participant's inputs here; hardware ignores them."""
        return None

    def feedback(self) -> dict[str, float]:
        """What the actuators currently deliver (simulated: the modelled output)."""
        return {}


class Participant(ABC):
    """A person at a device, or a virtual one acting through the same device and scene."""

    name: ClassVar[str]
    virtual: ClassVar[bool] = True

    def __init__(self, params: Mapping[str, Any] | None = None) -> None:
        self.params = dict(params or {})

    @abstractmethod
    def begin_trial(self, info: TrialInfo, rng: np.random.Generator) -> None: ...

    @abstractmethod
    def act(self, t: float, percept: Mapping[str, Any]) -> Action:
        """Decide this tick's inputs and requests from what was felt and seen so far."""

    def answer(self, item: Mapping[str, Any], rng: np.random.Generator) -> int:
        """Answer a questionnaire item (Likert code in the item's scale)."""
        raise NotSupportedError(f"{type(self).__name__} cannot answer questionnaires")

    def memory(self) -> Mapping[str, Any]:
        """What a virtual participant has learnt so far in the session and carries into later trials (JSON
        values). The engine stores it with every finished trial and hands the last one to :meth:`recall` when
        the session is resumed in a new process, so a resumed session behaves as an uninterrupted one.
        Empty (the default): nothing is carried."""
        return {}

    def recall(self, memory: Mapping[str, Any]) -> None:  # noqa: B027 - optional hook, nothing to restore by default
        """Restore what :meth:`memory` returned (called on resume, after ``begin_session``)."""


class IdleParticipant(Participant):
    """Nobody at the device: every tick the same empty action. Device contract checks, benchmarks and tests run a
    trial loop with it where only the device, controller and clock are being looked at."""

    name = "idle"
    _NOTHING = Action()  # one instance: a benchmark's hot loop should not time an allocation per tick

    def begin_trial(self, info: TrialInfo, rng: np.random.Generator) -> None:
        pass

    def act(self, t: float, percept: Mapping[str, Any]) -> Action:
        return self._NOTHING
