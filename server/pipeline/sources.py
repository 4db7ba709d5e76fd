"""Measurement sources: where the live pipeline's Measurements come from.

A simulated run, a recorded log and a live feed from a real machine are the same thing to
the observers (docs/design.md, "measurement source"): a stream of blocks of
:class:`machine.stage.Measurements`, with :class:`machine.stage.Truth` beside them only
when the source is the simulator. :class:`server.pipeline.live_pipeline.LivePipeline`
consumes any object that satisfies :class:`MeasurementSource`; it never asks which kind
of source it has. The sources: :class:`SimulatorSource` and :class:`ReplaySource` (a
measured log) here, :class:`server.pipeline.mqtt_source.MqttSource` (a machine's drive
data from a broker) beside them.

The interface
-------------
name : str
    ``"simulator"``, ``"replay"``, ``"mqtt"``...: the label the service shows, and the
    key of :meth:`MeasurementSource.status` in the pipeline's snapshot.
kind : str
    The model the observers use; ``"two_inertia"`` (motor and load positions).
sample_time : float
    Sample time [s] of every block.
nominal : machine.stage_params.StageParams
    The known (nominal) parameters the observers are built from (J_M, B_M, F_CM, K,
    and the load's J_L, B_L, F_CL the identifiers start from).
encoder_resolution : float
    Resolution of the position measurements [rad]; sets the observer's velocity filter.
has_truth : bool
    True when blocks carry a :class:`machine.stage.Truth` (the simulator only).
knobs_apply : bool
    True when the scenario's knobs change what the source produces (the simulator). A
    log or a live feed ignores :meth:`MeasurementSource.reconfigure`.
paced : bool
    True when the live loop paces the source by its clock (the simulator, a replayed
    log: ``speed`` applies). A live feed (MQTT) is not paced: it sets its own pace, and
    the loop takes its samples as they arrive.
t : float
    Time of the next sample, counted from the source's start [s]. Advances by
    ``sample_time`` per sample handed out (an empty block leaves it), and may jump only
    at a discontinuity (a live feed's missing samples).
finished : bool
    True once the source will hand out no more samples (the end of a log). A live feed
    that has nothing yet is not finished: its :meth:`MeasurementSource.step` returns an
    empty block.
step(n) -> SourceBlock
    Up to ``n`` next samples: exactly ``n`` from the simulator, fewer at the end of a log,
    fewer or none when a live feed has not received more. An empty block changes nothing.
reconfigure(**changes)
    The scenario's changes of the simulated plant (force, added inertia, noise, plant
    effects; fields of :class:`machine.stage.StageConfig`) from the next sample on.
reset()
    Back to the start: the simulator from t = 0 with its first configuration and seed,
    a log from its first sample.
state() -> object
    Where the source is, as a value of the state codec (:mod:`common.state_io`): the
    simulated stage (state, configuration, random generator), a log's position; a live
    feed's time only (the machine goes on without us: :class:`LiveSource`).
    ``restore(state)`` continues from it.
truth_summary() -> dict
    What the source knows beside the measurements, for the snapshot's ``truth``.
status() -> dict
    The source's own progress for the snapshot (empty for the simulator).

A :class:`SourceBlock` holds the block's Measurements, its Truth (or None) and
``discontinuity``: a reason (``"gap"``, ``"reset"``, ...) when this block does not
continue the previous one (a missing block, a time jump, a restarted drive). The
pipeline then resets every observer before it runs the block, so the estimates that
follow are those of a fresh pipeline on the same data; the observers' state never
bridges a gap. One exception, :data:`RESUMED`: the first block of a live feed after the
service restarted from a checkpoint (the machine and its load are the same): the filters
on the measurements restart, the estimates (parameters, covariances, segment tracks,
wear) go on.

Implementations: :class:`SimulatorSource` (the stage of :mod:`machine.stage`) and
:class:`ReplaySource` (a measured log, checked by :func:`open_replay`) here; the live
feeds :class:`server.pipeline.mqtt_source.MqttSource` (a broker) and
:class:`server.pipeline.opcua_source.OpcuaSource` (an OPC UA server), whose time
:class:`LiveSource` keeps; the machining centre's simulated CNC trace,
:class:`server.pipeline.centre_source.CentreSource`.

Replay validation (:func:`open_replay`): the file exists, passes
:func:`server.records.measured_log.load_log`, is of kind ``two_inertia`` with a ``q_l``
column, angles in rad, effort in N m (or A with K_t), and its sidecar gives the nominal
parameters J_M, J_L, K, K_t, B_M, B_L, F_CM, F_CL.
"""

from __future__ import annotations

import copy
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, NotRequired, Protocol, TypeAlias, TypedDict, runtime_checkable

import numpy as np

from common.arrays import F64
from common.errors import ParameterError
from machine.stage import SEED000_FORCE, Measurements, StageConfig, StageSim, Truth
from machine.stage_params import StageParams
from server.errors import CutwatchError, LogFormatError
from server.records.measured_log import MeasuredLog, load_log

#: the discontinuity of a live feed's first block after the service restarted from a
#: checkpoint: the filters on the measurements restart, the estimates go on
RESUMED = "resumed"
#: the nominal parameters a replayed log's sidecar must give
NOMINAL = ("J_M", "J_L", "K", "K_t", "B_M", "B_L", "F_CM", "F_CL")
#: what a source says of its truth (:meth:`MeasurementSource.truth_summary`): true
#: parameters and counts by name, a label (a log's path, a program, a server)
TruthSummary: TypeAlias = dict[str, float | str]


class Scheduled(TypedDict):
    """An event scheduled in a simulated part program (``POST /api/control`` inject: the
    default scenario's process part, :meth:`server.pipeline.process_part.LiveProcess.inject`;
    the machining centre's source): its kind and size (``unit``), when (``at_t`` [s] or
    ``at_part``, ``line``; ``now`` the time asked at) and where, in words."""

    kind: str
    size: float
    at_part: int | None
    where: str
    unit: NotRequired[str]
    at_t: NotRequired[float | None]
    now: NotRequired[float]
    line: NotRequired[int]


@dataclass(frozen=True)
class SourceBlock:
    """One block of a source: the Measurements, the Truth (simulator only) and whether
    the block continues the previous one.

    Attributes
    ----------
    meas : Measurements
        ``t`` counts from the source's start; ``f_ext`` is the reference force (NaN when
        the source has none).
    truth : Truth or None
        Only the simulator has it.
    discontinuity : str or None
        Why this block does not continue the previous one (``"gap"``, ``"reset"``...);
        the pipeline resets its observers before running it. None: it continues.
    columns : mapping of str to array
        Every signal of a described machine's block by its source's name (a live feed's
        column, an OPC UA node id: every axis, the spindle), one value per sample of
        ``meas``; empty for a source of one two-inertia axis without a description.
    """

    meas: Measurements
    truth: Truth | None = None
    discontinuity: str | None = None
    columns: Mapping[str, F64] = field(default_factory=dict)

    @property
    def n(self) -> int:
        """Number of samples (0: nothing this time)."""
        return len(self.meas.t)


@runtime_checkable
class MeasurementSource(Protocol):
    """What the live pipeline needs of a source (see the module docstring)."""

    @property
    def name(self) -> str: ...

    @property
    def kind(self) -> str: ...

    @property
    def sample_time(self) -> float: ...

    @property
    def nominal(self) -> StageParams: ...

    @property
    def encoder_resolution(self) -> float: ...

    @property
    def has_truth(self) -> bool: ...

    @property
    def knobs_apply(self) -> bool: ...

    @property
    def paced(self) -> bool: ...

    @property
    def t(self) -> float: ...

    @property
    def finished(self) -> bool: ...

    def step(self, n: int) -> SourceBlock: ...

    def reconfigure(self, **changes: object) -> None: ...

    def reset(self) -> None: ...

    def state(self) -> object: ...

    def restore(self, state: object) -> None: ...

    def truth_summary(self) -> TruthSummary: ...

    def status(self) -> dict[str, object]: ...


def empty_measurements() -> Measurements:
    """A block of zero samples."""
    z = np.zeros(0)
    return Measurements(t=z, i_m=z, tau_m=z, q_m=z, q_l=z, f_ext=z)


def no_truth(meas: Measurements) -> Truth:
    """The Truth of a block from a source without one: the reference force ``f_ext`` as
    the force to compare with (NaN when there is none), everything else NaN."""
    nan = np.full(len(meas.t), math.nan)
    return Truth(
        f_cut=meas.f_ext,
        omega_m=nan,
        omega_l=nan,
        t_s=nan,
        omega_ref=nan,
        J_L=nan,
        B_L=nan,
        F_CL=nan,
    )


class SimulatorSource:
    """The simulated stage (:class:`machine.stage.StageSim`) as a source.

    Parameters
    ----------
    config
        The stage's first configuration (the scenario's); :meth:`reset` returns to it.
    seed
        Seed of the simulation's random generator (current noise); :meth:`reset` reseeds.
    """

    name = "simulator"
    kind = "two_inertia"
    has_truth = True
    knobs_apply = True
    paced = True
    finished = False

    def __init__(self, config: StageConfig | None = None, seed: int = 0) -> None:
        self._config0 = config or StageConfig()
        self._seed = seed
        self.sim = StageSim(self._config0, seed=seed)

    @property
    def config(self) -> StageConfig:
        """The configuration in effect (changed by :meth:`reconfigure`)."""
        return self.sim.config

    @property
    def sample_time(self) -> float:
        return float(self.sim.config.sample_time)

    @property
    def nominal(self) -> StageParams:
        c = self.sim.config
        return c.nominal or c.params

    @property
    def encoder_resolution(self) -> float:
        return self.sim.config.encoder_resolution

    @property
    def t(self) -> float:
        return float(self.sim.t)

    def step(self, n: int) -> SourceBlock:
        """Exactly ``n`` simulated samples (``n`` >= 1)."""
        meas, truth = self.sim.step(n)
        return SourceBlock(meas, truth)

    def reconfigure(self, **changes: object) -> None:
        """Replace fields of the stage's configuration from the next sample on."""
        self.sim.reconfigure(**changes)

    def reset(self) -> None:
        """A fresh stage: t = 0, the first configuration, the seed's generator."""
        self.sim = StageSim(self._config0, seed=self._seed)

    def state(self) -> object:
        """The simulated stage itself (a copy: its state, configuration, generator)."""
        return copy.deepcopy(self.sim)

    def restore(self, state: object) -> None:
        """Continue the simulation of :meth:`state`.

        Raises
        ------
        ParameterError
            ``state`` is not a simulated stage.
        """
        if not isinstance(state, StageSim):
            raise ParameterError("source", "a simulated stage (StageSim)", type(state).__name__)
        self.sim = copy.deepcopy(state)

    def truth_summary(self) -> TruthSummary:
        """The true load parameters in effect (added inertia included)."""
        p = self.sim.config.true_params
        return {"J_L": p.J_L, "B_L": p.B_L, "F_CL": p.F_CL}

    def status(self) -> dict[str, object]:
        return {}


def open_replay(path: str | os.PathLike[str]) -> MeasuredLog:
    """Load and check a log for replay.

    Raises
    ------
    LogFormatError
        The file is missing or fails the log-format checks.
    CutwatchError
        Not a two-inertia log in rad / N m with the nominal parameters.
    """
    log = load_log(path, required=("t", "tau_m", "q_m", "q_l"))
    if log.kind != "two_inertia":
        raise CutwatchError(
            f"{log.path}: kind {log.kind!r}: expected 'two_inertia' (sidecar key 'kind')"
        )
    if log.units.get("position") != "rad" or log.units.get("effort") != "N m":
        raise CutwatchError(
            f"{log.path}: units {log.units!r}: expected position 'rad' and effort 'N m' "
            "(the live observers work on motor and load angles)"
        )
    missing = [k for k in NOMINAL if k not in log.nominal]
    if missing:
        raise CutwatchError(
            f"{log.path}: sidecar 'nominal' lacks {', '.join(missing)} "
            f"(expected {', '.join(NOMINAL)})"
        )
    if len(log["t"]) < 2:
        raise LogFormatError(f"{log.path}: expected at least 2 samples, found {len(log['t'])}")
    return log


def nominal_config(
    nominal: Mapping[str, Any], sample_time: float, encoder_resolution: float | None
) -> StageConfig:
    """A sidecar's (or a broker meta's) nominal parameters, sample time and encoder as a
    stage configuration for the observers (the encoder resolution rounded to a whole
    number of bits, as the observers assume).

    Raises
    ------
    ParameterError, TypeError, ValueError
        A parameter is missing, not a number or out of its range.
    """
    p = StageParams(**{k: float(nominal[k]) for k in NOMINAL}, C_s=float(nominal.get("C_s", 0.0)))
    bits = (
        20
        if encoder_resolution is None
        else round(math.log2(2 * math.pi / float(encoder_resolution)))
    )
    return StageConfig(
        params=p, force=SEED000_FORCE, sample_time=float(sample_time), encoder_bits=bits
    )


def _log_config(log: MeasuredLog) -> StageConfig:
    """The log's stage configuration (:func:`nominal_config`)."""
    try:
        return nominal_config(log.nominal, log.sample_time, log.sidecar.get("encoder_resolution"))
    except (ParameterError, TypeError, ValueError, KeyError) as exc:
        raise CutwatchError(f"{log.path}: nominal parameters: {exc}") from None


class ConfiguredSource:
    """What a source built from nominal parameters answers from its stage configuration
    (:func:`nominal_config`): the sample time, the nominal parameters, the encoder."""

    _cfg: StageConfig

    @property
    def sample_time(self) -> float:
        return float(self._cfg.sample_time)

    @property
    def nominal(self) -> StageParams:
        return self._cfg.params

    @property
    def encoder_resolution(self) -> float:
        return self._cfg.encoder_resolution


class LiveSource(ConfiguredSource):
    """What every live feed from a real machine (:class:`~server.pipeline.mqtt_source.
    MqttSource`, :class:`~server.pipeline.opcua_source.OpcuaSource`) does alike with its
    time: the machine is not ours to keep (it goes on without us) and cannot be rewound,
    but the source's time goes on from where it was.

    A subclass keeps its time in ``_t`` [s] and ``_resumed`` (the next block is marked
    :data:`RESUMED`), and forgets the feed's time origin in :meth:`_forget_origin`.
    """

    _t: float
    _resumed: bool

    def _forget_origin(self) -> None:
        """The next sample starts the source's time afresh from ``_t``."""
        raise NotImplementedError

    def reconfigure(self, **changes: object) -> None:
        """Knobs do not change a real machine."""

    def reset(self) -> None:
        """A live feed cannot rewind: time restarts at 0 with the next samples."""
        self._t = 0.0
        self._forget_origin()

    def state(self) -> object:
        """The source's time [s]."""
        return float(self._t)

    def restore(self, state: object) -> None:
        """Continue the time at ``state`` [s]; the next block is marked :data:`RESUMED`.

        Raises
        ------
        ParameterError
            Not a time.
        """
        if not isinstance(state, float) or not math.isfinite(state) or state < 0:
            raise ParameterError("source", "a time >= 0 s", state)
        self._t, self._resumed = state, True
        self._forget_origin()


class ReplaySource(ConfiguredSource):
    """A measured two-inertia log as a source: its samples in order, then finished.

    ``t`` counts from the log's first sample in steps of the log's sample time;
    ``f_ext`` is the log's reference force (NaN when it has none). No Truth; the knobs
    do not change a recorded log.

    Parameters
    ----------
    log
        From :func:`open_replay`.

    Raises
    ------
    CutwatchError
        The sidecar's nominal parameters are not valid stage parameters.
    """

    name = "replay"
    kind = "two_inertia"
    has_truth = False
    knobs_apply = False
    paced = True

    def __init__(self, log: MeasuredLog) -> None:
        self.log = log
        self._cfg = _log_config(log)
        self.k = 0
        self.n = len(log["t"])
        c = log.columns
        self._f: F64 = c["f_ext"] if "f_ext" in c else np.full(self.n, math.nan)

    @property
    def t(self) -> float:
        return self.k * self.sample_time

    @property
    def remaining(self) -> int:
        """Samples not handed out yet."""
        return self.n - self.k

    @property
    def finished(self) -> bool:
        return self.remaining <= 0

    def step(self, n: int) -> SourceBlock:
        """The next ``n`` samples of the log (fewer at its end, none after it)."""
        a, b = self.k, min(self.k + max(int(n), 0), self.n)
        self.k = b
        c = self.log.columns
        tau = c["tau_m"][a:b]
        meas = Measurements(
            t=np.arange(a, b, dtype=np.float64) * self.sample_time,
            i_m=c["i_m"][a:b] if "i_m" in c else tau / self._cfg.params.K_t,
            tau_m=tau,
            q_m=c["q_m"][a:b],
            q_l=c["q_l"][a:b],
            f_ext=self._f[a:b],
        )
        return SourceBlock(meas)

    def reconfigure(self, **changes: object) -> None:
        """Knobs do not change a recorded log."""

    def reset(self) -> None:
        """Back to the log's first sample."""
        self.k = 0

    def state(self) -> object:
        """The position in the log (samples handed out)."""
        return int(self.k)

    def restore(self, state: object) -> None:
        """Continue at position ``state`` of the same log.

        Raises
        ------
        ParameterError
            Not a position inside the log.
        """
        if not isinstance(state, int) or not 0 <= state <= self.n:
            raise ParameterError("source", f"a position in [0, {self.n}]", state)
        self.k = state

    def truth_summary(self) -> TruthSummary:
        return {"log": str(self.log.path), "samples": self.n}

    def status(self) -> dict[str, object]:
        return {
            "path": str(self.log.path),
            "samples": self.n,
            "fed": self.k,
            "finished": self.finished,
        }


__all__ = [
    "NOMINAL",
    "RESUMED",
    "ConfiguredSource",
    "LiveSource",
    "MeasurementSource",
    "ReplaySource",
    "Scheduled",
    "SimulatorSource",
    "SourceBlock",
    "TruthSummary",
    "empty_measurements",
    "no_truth",
    "nominal_config",
    "open_replay",
]
