"""Request and response models of every REST route (what ``/docs`` shows).

The stream's shapes that REST responses carry too (``LoopHealth``, ``Accuracy``) are
defined once, in :mod:`server.service.messages`.

Responses whose content the pipeline owns (snapshot, residual report) declare the keys
known today and let others through (``extra="allow"``), so a key added by the pipeline
reaches clients rather than being dropped by the response model.
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    JsonValue,
    PlainValidator,
    RootModel,
    model_validator,
)
from pydantic_core import PydanticCustomError

from common.event_kinds import ProcessEventKind
from server.pipeline.knobs import KnobValue
from server.pipeline.process_part import CLEAR_SIZES, SIZE_RANGES
from server.records.history import CAUSES
from server.service.messages import Accuracy, Event, LoopHealth, MonitorStatus, PartStatus
from server.service.settings import MAX_SPEED, ScenarioName, Speed

# ------------------------------------------------------------------ errors


class ErrorItem(BaseModel):
    """One refused field."""

    field: str = Field(description="the field, header or path part refused ('body': all of it)")
    allowed: str = Field(description="what it accepts")
    got: JsonValue = Field(description="what was found (non-finite numbers as 'nan', 'inf')")
    msg: str = Field(description="one sentence naming the three")


class ErrorBody(BaseModel):
    """The body of every 4xx answer."""

    detail: list[ErrorItem]


_ERROR_DOCS = {
    400: "the Host header does not name this service (CUTWATCH_ALLOWED_HOSTS)",
    401: "no or wrong credentials (a bearer token or a session; CUTWATCH_TOKEN set)",
    403: "the viewer role on an operator's request, or a cross-origin browser request",
    404: "no such report, route or file",
    405: "method not allowed on this path",
    409: "the request does not fit the service's state (nothing runs, already recording...)",
    413: "request body over the limit (CUTWATCH_MAX_BODY_BYTES; uploads: CUTWATCH_UPLOAD_MAX_MB)",
    422: "a field is missing, unknown or out of range; nothing changed",
}


def error_responses(*codes: int, json_route: bool = True) -> dict[int | str, dict[str, Any]]:
    """OpenAPI ``responses=`` for the given 4xx codes, plus ``4XX`` for any other; 400
    (Host), 401 (credentials) and 403 (role, Origin) on every route (the middleware's
    checks, ``server.service.middleware.Guard``).

    ``json_route=False`` for routes answering HTML or text: FastAPI would file a
    ``model`` under the route's own media type, but the error bodies are JSON.
    """
    docs: dict[int | str, str] = {c: _ERROR_DOCS[c] for c in (400, 401, 403, *codes)}
    docs["4XX"] = "any other client error, same shape"
    if json_route:
        return {c: {"model": ErrorBody, "description": d} for c, d in docs.items()}
    ref = {"$ref": "#/components/schemas/ErrorBody"}  # registered by the JSON routes
    return {
        c: {"description": d, "content": {"application/json": {"schema": ref}}}
        for c, d in docs.items()
    }


# ------------------------------------------------------------------ status


class Health(LoopHealth):
    """``GET /api/health``."""

    status: Literal["ok", "degraded", "idle", "error"] = Field(
        description="'error' once the loop has stopped; 'idle' while nothing is estimated "
        "(idle says why: no part runs, or a live feed has sent no sample yet); 'degraded' "
        "while a part of the pipeline does not run (parts says which and why); else 'ok'"
    )
    idle: str = Field(default="", description="why nothing is estimated (empty: something is)")
    parts: list[PartStatus] = Field(
        description="every part of the pipeline: name, running, and why not (reason)"
    )
    loop_error: str | None = Field(description="why the loop stopped, if it did")
    viser_port: int
    viser_running: bool
    scenario: str
    source: str = Field(description="where the measurements come from: simulator, replay, mqtt")
    feed: dict[str, Any] | None = Field(
        default=None,
        description=(
            "the broker feed (source mqtt): state (receiving, waiting for meta, refused, "
            "broker not connected), the broker's last refusal, and the counters of gaps, "
            "duplicates, late blocks, restarts, drops and malformed blocks by kind"
        ),
    )
    opcua: dict[str, Any] | None = Field(
        default=None,
        description=(
            "the OPC UA source (source opcua): state (connected, lost: why, no connection: "
            "why, refused: why, e.g. an untrusted server's thumbprint), the security policy, "
            "the sampling interval asked and revised, the queue size, and the grid's counts: "
            "samples, cells, values held per node, merged, late and lost samples, gaps"
        ),
    )
    estimates_out: dict[str, Any] | None = Field(
        default=None, description="the estimates publisher (mqtt_publish_hz > 0)"
    )
    events_out: dict[str, Any] | None = Field(
        default=None,
        description="the events and feed-hold commands publisher (a broker set): topics, "
        "connected, counts of events and commands handed over and refused",
    )


class MachineAxis(BaseModel):
    """A feed axis as the source delivers it."""

    name: str
    kind: str = Field(description="two_inertia (motor and load positions) or rigid")
    signals: list[str] = Field(description="the roles of its signals (q_m, q_l, i_m...)")


class MachineSpindle(BaseModel):
    """The spindle as the source delivers it."""

    signals: list[str] = Field(description="the roles of its signals (speed, power...)")


class Machine(BaseModel):
    """``GET /api/machine``: the machine the source delivers and the parts watching it."""

    source: str
    scenario: str
    sample_time: float = Field(description="[s]")
    axes: list[MachineAxis]
    spindle: MachineSpindle | None = Field(description="None: the source has no spindle")
    identities: list[str] = Field(description="the program's identities (tool, line...)")
    description: dict[str, Any] | None = Field(
        description="the machine description (common/machine.schema.json) when the source "
        "has one; None for the simulated stage"
    )
    parts: list[PartStatus] = Field(description="every part: name, running, and why not")


class Scenarios(BaseModel):
    """``GET /api/scenarios``."""

    current: str
    scenarios: dict[str, str] = Field(description="name -> description")


class PipelineEffect(BaseModel):
    """An installed observer effect as the pipeline reports it."""

    name: str
    shape: dict[str, float | None]
    coef: list[float | None]


class ReplayProgress(BaseModel):
    """How far a replay has fed its log."""

    path: str
    samples: int
    fed: int
    finished: bool


class PipelineSnapshot(BaseModel):
    """Latest values, truths and knob values of the running pipeline."""

    model_config = ConfigDict(extra="allow")
    t: float | None = Field(description="simulated (or replayed) time [s]")
    scenario: str
    latest: dict[str, float | None] = Field(description="channel -> latest value")
    truth: dict[str, JsonValue] = Field(description="the true parameters (or the log replayed)")
    knobs: dict[str, bool | float | str]
    observer_effects: list[PipelineEffect]
    replay: ReplayProgress | None = Field(None, description="present while replaying a log")
    accuracy: Accuracy
    parts: list[PartStatus] = Field(
        default_factory=list, description="the pipeline's parts: name, running, and why not"
    )
    axes: dict[str, dict[str, str]] | None = Field(
        None,
        description="a described machine's axes identified live (part 'axes'): per axis, "
        "what does not run and why (the mass without an acceleration at 10 Hz...)",
    )
    injected: list[dict[str, JsonValue]] = Field(
        default_factory=list,
        description="the truth of the latest injected events (kind, first sample's time t "
        "and index, size, tool, line, part): for scoring, never given to a detector",
    )


class Snapshot(BaseModel):
    """``GET /api/snapshot``."""

    pipeline: PipelineSnapshot
    health: LoopHealth
    events: list[Event] = Field(
        default_factory=list,
        description="the latest monitor events the service keeps (at most 200), newest "
        "first, with their acknowledgements (all of them: GET /api/events)",
    )
    status: MonitorStatus | None = Field(None, description="the monitor's status strip")


# ------------------------------------------------------------------ params


class _KnobBase(BaseModel):
    unit: str
    doc: str
    parts: list[str] = Field(
        default_factory=list,
        description="the parts of the running pipeline that read it ('simulator': the "
        "simulated stage)",
    )
    waiting: str = Field(
        "",
        description="why none of those parts runs now (the value is kept for when one "
        "does); empty: one runs",
    )
    page: Literal["operator", "research"] = Field(
        "research",
        description="the dashboard page it is set on: operator (the machine's tab) or research",
    )


class NumberKnob(_KnobBase):
    type: Literal["number"]
    value: float
    min: float | None
    max: float | None


class BoolKnob(_KnobBase):
    type: Literal["bool"]
    value: bool


class ChoiceKnob(_KnobBase):
    type: Literal["choice"]
    value: str
    choices: list[str]


KnobOut = Annotated[NumberKnob | BoolKnob | ChoiceKnob, Field(discriminator="type")]


class Params(RootModel[dict[str, KnobOut]]):
    """``GET``/``PATCH /api/params``: every live parameter with its allowed values."""


def _knob_value(v: Any) -> KnobValue:
    # the type of a knob's value; its range or choices are the pipeline's to check
    # (``LivePipeline.set_knob``, one message per knob)
    if isinstance(v, bool):
        return v
    if isinstance(v, str) and len(v) <= 100:
        return v
    if isinstance(v, int | float):
        try:
            f = float(v)
        except OverflowError:
            f = math.inf
        if math.isfinite(f):
            return f
    raise PydanticCustomError(
        "knob_value", "a finite number, true or false, or a choice's name (a short string)"
    )


#: the value of one knob in a PATCH: a finite number, a boolean or a short string
_PatchedValue = Annotated[KnobValue, PlainValidator(_knob_value)]


class ParamsPatch(RootModel[dict[str, _PatchedValue]]):
    """``PATCH /api/params``: ``{name: value}`` for one or more knobs (all or nothing).

    Each value is checked against its knob (a number in range, true or false, one of the
    choices); every refused field is listed in the 422.
    """

    model_config = ConfigDict(
        json_schema_extra={
            "additionalProperties": {
                "anyOf": [{"type": "number"}, {"type": "boolean"}, {"type": "string"}]
            },
            "examples": [{"spindle_rpm": 2400, "weight_on": True}],
        }
    )


# ------------------------------------------------------------------ control


#: the longest program name (relearn)
PROGRAM_CHARS = 32


def _refuse(field: str, allowed: str, got: Any) -> PydanticCustomError:
    """A request model's own refusal of ``field`` (the value found: ``got``)."""
    return PydanticCustomError(
        "refused", "{allowed}", {"field": field, "allowed": allowed, "got": got}
    )


class _Action(BaseModel):
    """One action of ``POST /api/control``: its fields and no other."""

    model_config = ConfigDict(extra="forbid")


class Pause(_Action):
    """Hold the loop (the simulated time stands still)."""

    action: Literal["pause"]


class Resume(_Action):
    """Run again at the speed set (1x after a speed of 0)."""

    action: Literal["resume"]


class Reset(_Action):
    """Restart the simulation and every estimator from t = 0 (knob values kept)."""

    action: Literal["reset"]


class SetSpeed(_Action):
    """Simulated seconds per wall second (0 pauses)."""

    action: Literal["speed"]
    value: Speed = Field(description=f"speed in [0, {MAX_SPEED:g}]")


class SetScenario(_Action):
    """Switch to another scenario: a fresh pipeline from t = 0, its default knobs."""

    action: Literal["scenario"]
    scenario: ScenarioName = Field(description="scenario name")


_SIZE_DOC = (
    "; ".join(
        f"{k}: {what} in ({lo:g}, {hi:g}]{' ' + unit if unit else ''}"
        for k, (lo, hi, unit, what) in SIZE_RANGES.items()
    )
    + " (breakage: at or above the feed per tooth the tooth is gone, below it is "
    "chipped); default: " + ", ".join(f"{k} {v:g}" for k, v in CLEAR_SIZES.items())
)


class Inject(_Action):
    """Schedule an event in the simulated part program (a tooth breaking or chipped, a
    collision or overload, a missing tool): ``kind``, its ``size`` (default: the
    reproduction's clear size) and when: ``at_t`` (simulated time [s]; in an air move the
    event waits for the next cut) or ``at_part`` (the middle of that part's first cut),
    at most one (neither: now)."""

    action: Literal["inject"]
    kind: ProcessEventKind = Field(description="the event to inject")
    size: float | None = Field(None, allow_inf_nan=False, description=_SIZE_DOC)
    at_t: float | None = Field(None, ge=0, allow_inf_nan=False, description="simulated time [s]")
    at_part: int | None = Field(None, ge=0, description="part counter")

    @model_validator(mode="after")
    def _when_and_size(self) -> Inject:
        if self.at_t is not None and self.at_part is not None:
            raise _refuse("at_t", "no time when at_part is given (one of them)", self.at_t)
        if self.size is not None:
            lo, hi, unit, what = SIZE_RANGES[self.kind]
            if not lo < self.size <= hi:
                allowed = f"a {what} in ({lo:g}, {hi:g}] {unit}".rstrip()
                raise _refuse("size", f"{allowed} (kind {self.kind})", self.size)
        return self


class Relearn(_Action):
    """Teach the monitor's limits again: of ``tool``, of ``program``, or all (neither)."""

    action: Literal["relearn"]
    tool: int | None = Field(None, ge=1, description="this tool only")
    program: str | None = Field(
        None, min_length=1, max_length=PROGRAM_CHARS, description="this program only"
    )


#: body of ``POST /api/control``: one of the actions, told apart by ``action``; a field
#: of another action is refused by name (server.service.error_handlers)
Control = Annotated[
    Pause | Resume | Reset | SetSpeed | SetScenario | Inject | Relearn,
    Field(discriminator="action"),
]


class ControlState(BaseModel):
    """``POST /api/control``: the loop's state after the action."""

    speed: float
    paused: bool
    sim_t: float
    scenario: str
    scheduled: dict[str, JsonValue] | None = Field(
        None, description="action inject: what the simulator scheduled (kind, size, t, part...)"
    )
    relearned: dict[str, JsonValue] | None = Field(
        None, description="action relearn: the tool, the program and the segments reset"
    )


# ------------------------------------------------------------------ replay, effects


class Replay(BaseModel):
    """``POST /api/replay``: a measured log of the service's data areas, by name."""

    model_config = ConfigDict(extra="forbid")
    name: str | None = Field(
        None,
        max_length=128,
        description="a two_inertia log in the recordings or uploads (.csv optional)",
    )
    area: Literal["recordings", "uploads"] | None = Field(
        None, description="where to look (default: recordings, then uploads)"
    )
    path: str | None = Field(
        None, max_length=4096, description="refused (422): files are named, never given by path"
    )


class ReplayStarted(BaseModel):
    """``POST /api/replay``: the log now feeding the observers."""

    scenario: Literal["replay"]
    name: str
    area: str
    samples: int
    sample_time: float = Field(description="[s]")
    duration_s: float
    reference_force: bool = Field(description="the log has an f_ext column")


class EffectsBody(BaseModel):
    """``POST /api/observer-effects``: a residual report (by name), or its effects list."""

    model_config = ConfigDict(extra="forbid")
    report: str | None = Field(
        None, max_length=128, description="the name of a residual report (GET /residual)"
    )
    observer_effects: list[dict[str, Any]] | None = Field(
        None, description="[{name, shape, coef}] as in report.json"
    )
    path: str | None = Field(
        None, max_length=4096, description="refused (422): reports are named, never given by path"
    )


class Effect(PipelineEffect):
    """An installed observer effect."""

    side: str = Field(description="which side of the two-inertia model it acts on")


class Effects(BaseModel):
    """``GET``/``DELETE /api/observer-effects``."""

    observer_effects: list[Effect]


class EffectsInstalled(Effects):
    """``POST /api/observer-effects``."""

    skipped: list[str] = Field(description="effects on the log's own clock, not installed")
    t: float = Field(
        description="the live time [s] from which the effects act (the stream's t: compare "
        "the error before and after it)"
    )


class AxisModelBody(BaseModel):
    """``POST /api/axis-model``: a rigid residual report (by name, or the report itself)
    whose effects an axis' live rigid model holds (issue 30 item 4)."""

    model_config = ConfigDict(extra="forbid")
    axis: str | None = Field(
        None, max_length=64, description="the feed's axis (default: every axis)"
    )
    name: str | None = Field(
        None, max_length=128, description="the name of a residual report (GET /residual)"
    )
    report: dict[str, Any] | None = Field(
        None, description="a residual report (report.json of cutwatch residual) as JSON"
    )


class AxisModels(BaseModel):
    """The effects each axis' live rigid model holds (``GET``/``POST /api/axis-model``)."""

    axes: dict[str, list[str]] = Field(description="axis -> the names of its effects")
    t: float = Field(description="the live time [s] from which they act")


class ResidualReport(BaseModel):
    """``report.json`` of ``cutwatch residual`` (main keys; the file has more)."""

    model_config = ConfigDict(extra="allow")
    log: str
    kind: str
    n_samples: int
    sample_time: float
    selected: list[JsonValue]
    observer_effects: list[JsonValue] | None = None


# ------------------------------------------------------------------ data: records, uploads

_NAME_DOC = "a plain name: 1-128 of A-Z a-z 0-9 _ . - starting with a letter or digit"


class RecordBody(BaseModel):
    """``POST /api/record``: start or stop recording the live source."""

    model_config = ConfigDict(extra="forbid")
    action: Literal["start", "stop"]
    name: str | None = Field(
        None,
        max_length=128,
        description=f"start: the recording's name ({_NAME_DOC}; '.csv' added when missing); "
        "default rec-<UTC time>.csv",
    )


class RecordInfo(BaseModel):
    """One recording (in progress or on disk)."""

    name: str = Field(description="file name in the recordings area (GET /api/records/{name})")
    samples: int | None
    seconds: float | None = Field(description="duration of the samples written [s]")
    bytes: int | None = Field(description="size of the CSV [bytes]")
    active: bool = Field(description="still recording")
    end: str | None = Field(None, description="why it ended (stopped, a limit, a gap...)")


class RecordState(BaseModel):
    """``POST /api/record``: the recording started or stopped."""

    recording: RecordInfo


class Records(BaseModel):
    """``GET /api/records``: the recordings area, the one in progress first."""

    records: list[RecordInfo]


class UploadInfo(BaseModel):
    """One uploaded file."""

    name: str
    bytes: int
    kind: Literal["log", "sidecar"]
    checked: bool | None = Field(
        None, description="log: passed the log loader's checks (with its sidecar, if any)"
    )
    samples: int | None = None
    sample_time: float | None = None
    log_kind: str | None = Field(None, description="rigid or two_inertia (sidecar key 'kind')")


class Uploads(BaseModel):
    """``GET /api/uploads``."""

    uploads: list[UploadInfo]


# ------------------------------------------------------------------ analyses


class AnalysisBody(BaseModel):
    """``POST /api/analyses``: run ``cutwatch residual`` on a recording or an upload."""

    model_config = ConfigDict(extra="forbid")
    log: str = Field(..., min_length=1, max_length=128, description="the log's name")
    area: Literal["recordings", "uploads"] | None = Field(
        None, description="where the log is (default: recordings, then uploads)"
    )
    report: str | None = Field(
        None,
        max_length=120,
        description=f"the report's name ({_NAME_DOC}); default: the log's stem "
        "(-2, -3... when taken)",
    )
    holdout: float | None = Field(
        None, ge=0.1, le=0.5, description="fraction held out at the end (--holdout)"
    )
    kind: Literal["rigid", "two_inertia"] | None = Field(
        None, description="the model (--kind; default: the sidecar's)"
    )


class AnalysisJob(BaseModel):
    """``POST /api/analyses`` and ``GET /api/analyses/{id}``: one analysis job."""

    id: str
    log: str
    area: str
    report: str = Field(description="the report's name once done (GET /residual/{report}/)")
    options: dict[str, JsonValue]
    state: Literal["queued", "running", "done", "failed"]
    progress: float = Field(description="0..1 (steps seen over the most the analysis can take)")
    step: str = Field(description="the analysis step under way")
    message: str = Field(description="why it failed (the command's message)")
    started: float = Field(description="[s since the epoch]")
    finished: float | None
    selected: list[str] = Field(description="effects the report selected")
    observer_effects: int = Field(description="effects installable in the live observer")
    rms_before: float | None
    rms_after: float | None
    report_url: str | None


class AnalysisJobs(BaseModel):
    """``GET /api/analyses``: the recent jobs, newest last."""

    jobs: list[AnalysisJob]


# ------------------------------------------------------------------ history (events, tool life)


class AckBody(BaseModel):
    """``POST /api/events/{id}/ack`` (the body is optional)."""

    model_config = ConfigDict(extra="forbid")
    by: str | None = Field(
        default=None,
        min_length=1,
        max_length=128,
        description="who acknowledges (default: the session's role, 'operator')",
    )


class HistoryEvent(Event):
    """An event as the history keeps it: the stream's :class:`Event` and when it arrived."""

    received_wall: float = Field(description="when the history received it [unix s]")


class HistoryEvents(BaseModel):
    """A page of events, newest first."""

    total: int = Field(description="events matching the filters (all pages)")
    items: list[HistoryEvent]


class ToolLife(BaseModel):
    """One tool's life in the spindle, from its mounting to its change."""

    machine: str
    tool: int = Field(description="tool number (the CNC's; else the tool's place in the run)")
    index: int | None = Field(description="the tool's place in the run (1: the first)")
    start_t: float | None = Field(description="source time it was mounted [s] (null: unknown)")
    end_t: float = Field(description="source time it was changed [s]")
    start_wall: float | None = Field(description="when it was mounted [unix s] (null: unknown)")
    end_wall: float = Field(description="when it was changed [unix s]")
    wear_at_change_mm: float | None = Field(
        description="estimated flank wear at the change [mm] (null: no estimate yet)"
    )
    wear_true_mm: float | None = Field(
        description="the simulator's true flank wear at the change [mm] (null: no truth)"
    )
    wear_true_share: float | None = Field(
        description="the simulator's true wear at the change as a share of the tool's limit "
        "(null: no truth)"
    )
    cause: str = Field(description="why: " + ", ".join(CAUSES))
    wear_measured_mm: float | None = Field(
        default=None,
        description="flank wear measured at the change [mm], entered over REST "
        "(POST /api/tool-life/vb; null: none entered)",
    )


class ToolVb(BaseModel):
    """``POST /api/tool-life/vb``: the flank wear measured on a tool taken out at a tool
    change (issue 35 item 7): it labels that tool's latest ended life on this machine."""

    model_config = ConfigDict(extra="forbid")
    tool: int = Field(ge=1, le=10**6, description="the tool number (the CNC's T)")
    vb_mm: float = Field(
        gt=0.0, le=0.9, allow_inf_nan=False, description="the measured flank wear VB [mm]"
    )


class ToolVbLabel(BaseModel):
    """The life a measured VB labelled, and whether the tool's wear map is now this
    machine's own (calibrated)."""

    tool: int
    index: int = Field(description="the tool's instance whose life ended (1: the first)")
    end_t: float = Field(description="source time the change was seen [s]")
    vb_mm: float = Field(description="the VB entered [mm]")
    vb_est_mm: float = Field(description="the estimate at the change [mm]")
    calibrated: bool
    recorded: bool = Field(
        description="whether the tool-life record of that change (GET /api/tool-life) now "
        "holds the VB (false: a service keeping no history, or the change not yet kept)"
    )


class ToolLives(BaseModel):
    """A page of tool lives, newest first."""

    total: int
    items: list[ToolLife]
