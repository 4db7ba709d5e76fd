"""A machine's drive data from an MQTT broker as a measurement source.

:class:`MqttSource` satisfies :class:`server.pipeline.sources.MeasurementSource` over a
:class:`server.pipeline.drive_feed.DriveFeed`: each :meth:`MqttSource.step` hands out the
samples received so far (up to ``n``; none when nothing has arrived), and marks the first
block after a gap, a time jump, a restart or a dropped flood as a discontinuity, so the
pipeline resets its observers instead of bridging the hole.

What the observers are built from (sample time, nominal parameters, encoder) comes from
the retained ``meta`` message. Until it has arrived the source hands out nothing
(``status()["state"] == "waiting for meta"``); when a new meta changes those, the source
says ``needs_rebuild`` and the live loop builds a new pipeline on :meth:`renewed` (the
clients get a new hello).

Any machine the description allows is taken (issue 30): its first axis gives the
measurements the two-inertia observers read (``q_m``, ``q_l``, the effort, ``f_ext``:
NaN where the axis has none), every column travels beside them by its source's name
(``SourceBlock.columns``: the axes' identification reads them), and the spindle's speed
signal, when there is one, is the spindle speed in effect (:attr:`MqttSource.spindle_rpm`,
in rpm; the DFO follows it). The two-inertia observers' nominal comes from the first
axis' nominal when it is a two-inertia axis with all of it; else the parts that need it
say why (:class:`~server.pipeline.machine_view.MachineView`), nothing is refused.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from common.errors import ParameterError
from common.machine_description import AxisDescription, MachineDescription
from machine.stage import SEED000_FORCE, Measurements, StageConfig
from machine.stage_params import preset
from server.pipeline.drive_feed import DriveFeed
from server.pipeline.part import nan_to_num
from server.pipeline.sources import (
    NOMINAL,
    RESUMED,
    LiveSource,
    SourceBlock,
    TruthSummary,
    empty_measurements,
    nominal_config,
)

if TYPE_CHECKING:
    from common.arrays import F64


class MqttSource(LiveSource):
    """The live feed of one machine (see the module docstring)."""

    name = "mqtt"
    kind = "two_inertia"
    has_truth = False
    knobs_apply = False
    paced = False
    finished = False

    def __init__(self, feed: DriveFeed) -> None:
        self.feed = feed
        self._gen = feed.meta_generation
        meta = feed.meta
        self.problem = ""
        self._cfg = StageConfig(params=preset("seed000"), force=SEED000_FORCE)
        self.ready = False
        self.description: MachineDescription | None = None
        #: the first axis' nominal parameters are complete (the two-inertia observers'
        #: design); else they run from seed 000's preset, and say so
        self.nominal_given = False
        #: the spindle speed in effect [rpm] (NaN: the machine sends none yet)
        self.spindle_rpm = math.nan
        if meta is not None:
            self._configure(meta)
        self._t = 0.0
        self._t0: float | None = None
        self._taken = 0
        self._resumed = False  # restored from a checkpoint: the next block says so
        self.last_wall: float | None = None

    def _configure(self, meta: dict[str, Any]) -> None:
        desc = self.feed.description
        if desc is None or not desc.axes:
            self.problem = "meta describes no axis"
            return
        self.description = desc
        ax = desc.axes[0]
        self.kind = ax.kind
        self._cfg = StageConfig(
            params=preset("seed000"), force=SEED000_FORCE, sample_time=desc.sample_time
        )
        self.ready = True
        nom = dict(ax.nominal)
        if ax.K_t is not None:
            nom.setdefault("K_t", ax.K_t)
        if ax.kind != "two_inertia" or any(k not in nom for k in NOMINAL):
            return
        try:
            self._cfg = nominal_config(nom, desc.sample_time, ax.encoder_resolution)
        except (ParameterError, TypeError, ValueError) as exc:
            self.problem = f"meta nominal parameters: {exc}"
            self.ready = False
            return
        self.nominal_given = True

    # -- MeasurementSource -------------------------------------------------------------

    @property
    def t(self) -> float:
        return self._t

    @property
    def feed_origin(self) -> float | None:
        """The feed's time (the publisher's ``t0`` clock) at this source's time 0 [s]: a
        sample at source time ``t`` is at ``t + feed_origin`` on the machine's own clock
        (its log's, its edge device's). The source's time counts from the first sample
        it received, so a pipeline that joined a running feed is behind the machine's
        clock by this much (None before the first sample). A consumer that matches the
        events' ``t`` to the machine's record adds it (``cutwatch worker``'s
        ``/api/machines/<m>``: ``feed_origin_s``). It holds since its last change only:
        a restored checkpoint or a publisher that restarted sets it anew (time goes on
        from where it was, so the origin moves by what was missed), and events raised
        before that change need the origin read then; the plant's bench runs no such
        restart."""
        return self._t0

    @property
    def rate_known(self) -> bool:
        """True once a meta described the machine: before it, :attr:`sample_time` is the
        simulator's default, a placeholder no one is told (the hello says null)."""
        return self.description is not None

    @property
    def needs_rebuild(self) -> bool:
        """True when a (new) meta arrived after this source was built."""
        return self.feed.meta_generation != self._gen

    def renewed(self) -> MqttSource:
        """A source on the same feed, built from its current meta."""
        return MqttSource(self.feed)

    def step(self, n: int) -> SourceBlock:
        if not self.ready or self.needs_rebuild:
            return SourceBlock(empty_measurements())
        take = self.feed.take(max(int(n), 0))
        if take.n == 0:
            return SourceBlock(empty_measurements())
        c = take.columns
        ts = self.sample_time
        assert self.description is not None  # ready
        meas_cols = _axis_measurements(self.description.axes[0], c, self._cfg.params.K_t, take.n)
        self._spindle(c)
        disc = ("; ".join(take.reasons) or "gap") if take.discontinuity else None
        if self._resumed:  # the first block after a restart (sources.RESUMED)
            disc, self._resumed = RESUMED, False
        t0 = float(take.t[0])
        if self._t0 is None:  # the source's time counts from its first sample
            self._t0 = t0 - self._t
        elif disc is not None and t0 - self._t0 < self._t:
            self._t0 = t0 - self._t  # the publisher restarted: time goes on, never back
        # on the sample grid, as a replayed log's (sample index x sample time); across a
        # gap the index jumps forward with the feed's time
        k0 = round((t0 - self._t0) / ts)
        t = (k0 + np.arange(take.n, dtype=np.float64)) * ts
        self._t = float(t[-1] + ts)
        self._taken += take.n
        meas = Measurements(t=t, **meas_cols)
        self.last_wall = self.feed.last_wall
        return SourceBlock(meas, None, disc, columns=self._with_identities(dict(c), take))

    def _with_identities(self, cols: dict[str, F64], take: Any) -> dict[str, F64]:
        """The block's columns with the CNC's identities (the drive header's segments) under
        the description's identity columns, as a log or the simulated centre gives them
        (the spindle and axis parts key their monitors' blocks on them); a tool or line
        not known is 0, as on the wire."""
        assert self.description is not None  # ready
        for role, v in (take.identities or {}).items():
            name = self.description.identities.get(role)
            if name and name not in cols:
                a = np.asarray(v, dtype=np.float64)
                cols[name] = a if role == "override" else nan_to_num(a)
        return cols

    def _spindle(self, columns: dict[str, F64]) -> None:
        """The spindle speed in effect from the block's speed signal [rpm]: the block's
        last finite value, kept until it moves by more than 0.5 % (a CNC's speed
        fluctuates; the DFO is retuned only on a real change)."""
        sp = self.description.spindle if self.description is not None else None
        if sp is None or "speed" not in sp.signals or sp.signals["speed"] not in columns:
            return
        v = np.asarray(columns[sp.signals["speed"]], dtype=np.float64)
        v = v[np.isfinite(v)]
        if not len(v):
            return
        rpm = abs(float(v[-1])) * _RPM[sp.unit("speed")]
        old = self.spindle_rpm
        if not math.isfinite(old) or abs(rpm - old) > 0.005 * max(abs(old), 1.0):
            self.spindle_rpm = rpm

    def reset(self) -> None:
        """:meth:`LiveSource.reset`; the spindle speed is unknown again."""
        super().reset()
        self.spindle_rpm = math.nan

    def _forget_origin(self) -> None:
        self._t0 = None

    def truth_summary(self) -> TruthSummary:
        return {"machine": self.feed.machine}

    def status(self) -> dict[str, object]:
        if self.problem:
            state = "refused"
        elif not self.ready:
            state = "waiting for meta"
        elif not self.feed.connected:
            state = "broker not connected"
        else:
            state = "receiving"
        return {"state": state, "problem": self.problem, **self.feed.health()}


#: a spindle speed's unit -> rpm
_RPM = {"rpm": 1.0, "rad/s": 60.0 / (2.0 * math.pi), "1/s": 60.0}


def _axis_measurements(
    ax: AxisDescription, c: dict[str, F64], k_t: float, n: int
) -> dict[str, F64]:
    """The first axis' measurements for the two-inertia observers, by role (NaN where
    the axis has none): the motor and load positions, the torque and the current (one
    from the other through K_t), the measured force."""
    nan = np.full(n, math.nan)

    def col(role: str) -> Any:
        src = ax.signals.get(role)
        return c[src] if src is not None and src in c else nan

    tau, i_m = col("tau_m"), col("i_m")
    if "tau_m" in ax.signals:
        i_m = tau / k_t if "i_m" not in ax.signals else i_m
    else:
        tau = i_m * k_t
    return {"i_m": i_m, "tau_m": tau, "q_m": col("q_m"), "q_l": col("q_l"), "f_ext": col("f_ext")}
