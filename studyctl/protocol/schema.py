"""The protocol language: strict pydantic models of everything a study protocol says.

Unknown keys are errors, types are not coerced (``"90"`` is not a number, ``1.0`` is not a version
string), and every section has defaults only where a paper-faithful default exists. Cross-references
(condition ids in orders, instrument ids in administrations) are checked in
:mod:`studyctl.protocol.checks`, which also sees files that fail here.

Controller, device, scene and participant ``params`` are free-form mappings: each plugin validates
its own parameters.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, PrivateAttr

from studyctl.errors import ProtocolError
from studyctl.suggest import named

FORMAT_VERSION = 1
ID_PATTERN = r"^[A-Za-z][A-Za-z0-9_\-]*$"

# Limits on sizes and counts: a protocol is checked against them by `protocol check` (file:line errors), so
# a typo such as `repetitions: 1000000000000` or a 1e8 × 1e8 grid never reaches enrollment or a session.
MAX_SECONDS = 24 * 3600.0  # any duration: time limits, breaks, familiarisation
MAX_REPETITIONS = 1_000
MAX_BLOCKS = 100
MAX_GRID = 1_000  # columns or rows of a report grid
MAX_SITES = 1_000
MAX_LIST = 1_000  # conditions, strata, items, instruments, orders, choices …
MAX_SCALE_POINTS = 101
MAX_TRIALS = 10_000  # trials in one session: conditions × repetitions × blocks (checked in checks.py)
MAX_COUNT = 1_000_000  # target sample sizes, report counts

Id = Annotated[str, Field(pattern=ID_PATTERN, max_length=64)]
Seconds = Annotated[float, Field(gt=0, le=MAX_SECONDS, allow_inf_nan=False)]
Finite = Annotated[float, Field(allow_inf_nan=False)]
VisualMode = Literal["none", "on_request", "realtime"]
Scheme = Literal["williams", "cyclic_latin", "explicit", "random", "all_permutations"]
Allocation = Literal["alternating", "blocked", "shuffled"]
When = Literal["start", "after_trial", "after_condition", "after_block", "end"]


class StrictModel(BaseModel):
    """Base of every protocol section: unknown keys are errors, values are not coerced, instances frozen."""

    model_config = ConfigDict(extra="forbid", strict=True, frozen=True)


class StudyMeta(StrictModel):
    """Who runs the study and what it is: id, title, protocol version, citation, default seed."""

    id: Id
    title: str
    version: str
    description: str = ""
    reference: str | None = None
    ethics: str | None = None
    seed: int | None = Field(None, ge=0, lt=2**63)
    # the consent form's version; `studyctl consent CODE --version V` must name it when it is declared
    consent_version: str | None = Field(None, min_length=1, max_length=40)


class PluginRef(StrictModel):
    """A plugin by entry-point name, with the parameters its own ``validate`` checks."""

    plugin: Id
    params: dict[str, Any] = Field(default_factory=dict)


class Devices(StrictModel):
    """The device used with real participants (``hardware``) and the one used in simulation."""

    hardware: PluginRef | None = None
    simulated: PluginRef


class Stratum(StrictModel):
    """A between-subject group (novice, expert); counterbalancing runs within each stratum."""

    id: Id
    label: str = ""
    target_n: int | None = Field(None, ge=1, le=MAX_COUNT)


class ParticipantsSpec(StrictModel):
    """Strata, target sample size, pseudonym prefix, withdrawal policy and the virtual participant."""

    strata: list[Stratum] = Field(default_factory=lambda: [Stratum(id="all")], min_length=1, max_length=MAX_LIST)
    target_n: int | None = Field(None, ge=1, le=MAX_COUNT)
    replace_withdrawn: bool = False
    code_prefix: str = Field("P", pattern=r"^[A-Z][A-Z0-9]{0,7}$")
    virtual: PluginRef | None = None


class Condition(StrictModel):
    """One within-subject condition: the controller that runs (None for a manual condition), its
    parameters and the visual-feedback mode (``none``, ``on_request`` scans, ``realtime``).

    In a ``manual`` condition no controller runs and the coordinator enters the outcome.
    """

    id: Id
    label: str = ""
    description: str = ""
    controller: Id | None = None
    params: dict[str, Any] = Field(default_factory=dict)
    visual: VisualMode = "none"
    manual: bool = False
    # What the participant's screen may call this condition (e.g. "Session A"); blank: nothing, only
    # "Trial N". Never the id or label by default, so the participant stays blind to the condition.
    view_label: str = Field("", max_length=40)


class Counterbalance(StrictModel):
    """How the order of conditions varies across participants.

    ``fixed_first`` conditions always come first; ``scheme`` orders the rest (``conditions``, by
    default every other condition in declared order). ``allocation`` maps an enrollment slot to a
    sequence: ``alternating`` (slot mod number of sequences), ``blocked`` (``block_size`` consecutive
    slots per sequence) or ``shuffled`` (a seeded shuffle within each complete set of sequences).
    """

    scheme: Scheme
    conditions: list[Id] | None = Field(None, max_length=MAX_LIST)
    fixed_first: list[Id] = Field(default_factory=list, max_length=MAX_LIST)
    orders: list[Annotated[list[Id], Field(max_length=MAX_LIST)]] | None = Field(None, max_length=MAX_LIST)
    allocation: Allocation = "alternating"
    block_size: int | None = Field(None, ge=1, le=MAX_COUNT)
    within_strata: bool = True


class Design(StrictModel):
    """Blocks and repetitions: each condition runs ``repetitions`` consecutive trials; the whole
    condition sequence runs ``blocks`` times (in the same or the reverse order)."""

    repetitions: int = Field(1, ge=1, le=MAX_REPETITIONS)
    blocks: int = Field(1, ge=1, le=MAX_BLOCKS)
    block_order: Literal["same", "reverse"] = "same"


class Familiarisation(StrictModel):
    """Practice before the measured trials: at most ``max_s`` seconds, may end early on request."""

    max_s: Seconds
    can_end_early: bool = True
    when: Literal["before_each_condition", "once"] = "before_each_condition"
    instructions: str = ""


class Grid(StrictModel):
    """The coordinate map a participant reports on (columns × rows, optional cell size)."""

    columns: int = Field(ge=1, le=MAX_GRID)
    rows: int = Field(ge=1, le=MAX_GRID)
    cell_mm: float | None = Field(None, gt=0, le=10_000, allow_inf_nan=False)


class ReportSpec(StrictModel):
    """What the participant reports: a grid cell, a position, or nothing (outcome is the pose).

    ``hit_radius`` counts a report as correct within that distance of a true site: in grid cells for
    ``grid_cell``, in millimetres for ``position``. ``count_known`` says whether the participant is told
    how many targets there are.
    """

    kind: Literal["grid_cell", "position", "none"]
    grid: Grid | None = None
    hit_radius: float | None = Field(None, ge=0, le=100_000, allow_inf_nan=False)
    count_known: bool = False
    max_reports: int | None = Field(None, ge=1, le=MAX_COUNT)


class TrialTemplate(StrictModel):
    """What every trial looks like: hard time limit, familiarisation, breaks, report, allowed requests."""

    time_limit_s: Seconds | None = None
    familiarisation: Familiarisation | None = None
    break_s: float = Field(0.0, ge=0, le=MAX_SECONDS, allow_inf_nan=False)
    break_between: Literal["trials", "conditions"] = "trials"
    report: ReportSpec
    requests: list[Literal["scan", "report", "finish"]] = Field(default_factory=lambda: ["report", "finish"])
    instructions: str = ""


class Placement(StrictModel):
    """Targets (``items``, e.g. tumour classes) placed pseudo-randomly in numbered ``sites`` (holes).

    ``differ_from_previous``: ``assignment`` (the item→site map differs from the previous trial),
    ``every_item`` (every item moves to another site) or ``none``.
    """

    sites: int = Field(ge=1, le=MAX_SITES)
    items: list[Id] = Field(min_length=1, max_length=MAX_LIST)
    differ_from_previous: Literal["none", "assignment", "every_item"] = "assignment"


class Orientation(StrictModel):
    """A random orientation of the phantom/model, drawn from ``choices_deg`` per condition, block or trial."""

    choices_deg: list[Finite] = Field(default_factory=lambda: [0.0, 90.0, 180.0, 270.0], min_length=1,
                                      max_length=MAX_LIST)
    per: Literal["condition", "block", "trial"] = "condition"
    differ_from_previous: bool = False


class SceneSpec(StrictModel):
    """The scene plugin, its parameters and how it is randomised between trials."""

    plugin: Id
    params: dict[str, Any] = Field(default_factory=dict)
    placement: Placement | None = None
    orientation: Orientation | None = None


class Scale(StrictModel):
    """A rating scale: ``points`` codes starting at ``start`` (1..5 by default), labelled anchors by code."""

    points: int = Field(ge=2, le=MAX_SCALE_POINTS)
    start: int = Field(1, ge=-MAX_COUNT, le=MAX_COUNT)
    anchors: dict[int, str] = Field(default_factory=dict)

    @property
    def codes(self) -> tuple[int, ...]:
        """Every valid answer code, lowest first."""
        return tuple(range(self.start, self.start + self.points))


class Item(StrictModel):
    """One questionnaire item; ``scale`` overrides the instrument's scale; ``reverse`` marks reverse keying."""

    id: Id
    text: str
    scale: Scale | None = None
    reverse: bool = False


class Instrument(StrictModel):
    """A versioned questionnaire: items answered on a scale of coded points."""

    id: Id
    version: str
    title: str = ""
    reference: str | None = None
    scale: Scale | None = None
    items: list[Item] = Field(min_length=1, max_length=MAX_LIST)

    def scale_of(self, item: Item) -> Scale:
        """The scale an item is answered on (its own, else the instrument's)."""
        scale = item.scale or self.scale
        if scale is None:  # checks.py reports this; a loaded protocol never gets here
            raise ProtocolError(f"item {item.id!r} of instrument {self.id!r} has no scale; give the instrument "
                                "(or the item) a scale")
        return scale


class Administration(StrictModel):
    """When an instrument is given: at start, after each trial/condition/block, or at the end;
    ``conditions`` restricts per-trial/condition administrations to those conditions."""

    instrument: Id
    when: When
    conditions: list[Id] | None = None


class ResumePolicy(StrictModel):
    """What happens to a trial interrupted by a crash or stop: run it again (``repeat``) or mark it
    invalid and append a replacement at the end of the plan (``invalidate_and_append``)."""

    interrupted_trial: Literal["repeat", "invalidate_and_append"] = "repeat"
    checkpoint: Literal["trial", "condition"] = "trial"


class Protocol(StrictModel):
    """A whole study protocol, as loaded from ``protocols/<name>.yaml``.

    Use :func:`studyctl.protocol.load_protocol` to obtain one: it adds ``source_text``, ``sha256`` and
    ``path`` and runs every cross-reference check.
    """

    studyctl_protocol: Literal[1]
    study: StudyMeta
    devices: Devices
    participants: ParticipantsSpec = Field(default_factory=ParticipantsSpec)
    conditions: list[Condition] = Field(min_length=1, max_length=MAX_LIST)
    counterbalance: Counterbalance
    design: Design = Field(default_factory=Design)
    trial: TrialTemplate
    scene: SceneSpec
    instruments: list[Instrument] = Field(default_factory=list, max_length=MAX_LIST)
    questionnaires: list[Administration] = Field(default_factory=list, max_length=MAX_LIST)
    resume: ResumePolicy = Field(default_factory=ResumePolicy)

    _source_text: str = PrivateAttr(default="")
    _sha256: str = PrivateAttr(default="")
    _path: str = PrivateAttr(default="")

    @property
    def source_text(self) -> str:
        """The exact text the protocol was loaded from (stored with the study)."""
        return self._source_text

    @property
    def sha256(self) -> str:
        """Hex SHA-256 of ``source_text`` encoded as UTF-8: identifies the protocol in stored schedules."""
        return self._sha256

    @property
    def path(self) -> str:
        """The file the protocol came from ('' when loaded from text)."""
        return self._path

    @property
    def condition_ids(self) -> tuple[str, ...]:
        """Condition ids in declared order."""
        return tuple(c.id for c in self.conditions)

    @property
    def stratum_ids(self) -> tuple[str, ...]:
        """Stratum ids in declared order."""
        return tuple(s.id for s in self.participants.strata)

    def condition(self, condition_id: str) -> Condition:
        """The condition with this id (:class:`~studyctl.errors.UnknownKeyError`, a ``KeyError``, if none)."""
        return named(self.conditions, condition_id, what="condition", plural="conditions")

    def instrument(self, instrument_id: str) -> Instrument:
        """The questionnaire instrument with this id (:class:`~studyctl.errors.UnknownKeyError` if none)."""
        return named(self.instruments, instrument_id, what="instrument", plural="instruments")

    def stratum(self, stratum_id: str) -> Stratum:
        """The stratum with this id (:class:`~studyctl.errors.UnknownKeyError` if none)."""
        return named(self.participants.strata, stratum_id, what="stratum", plural="strata")


# Section models reachable by a key path: used to list the allowed keys of an unknown-key error.
SECTION_MODELS: tuple[type[StrictModel], ...] = (
    Protocol,
    StudyMeta,
    PluginRef,
    Devices,
    Stratum,
    ParticipantsSpec,
    Condition,
    Counterbalance,
    Design,
    Familiarisation,
    Grid,
    ReportSpec,
    TrialTemplate,
    Placement,
    Orientation,
    SceneSpec,
    Scale,
    Item,
    Instrument,
    Administration,
    ResumePolicy,
)
