"""The spindle's cutting power as a live part: its power less the idle power taught in air.

:class:`SpindlePart` (issue 31 phase 2, step b) reads a described machine's spindle
signals (its ``speed`` [rpm] and ``power`` [W], by the machine description's column
names) and runs :class:`estimators.monitoring.spindle_power.IdlePower`: the idle power taught per
speed while the spindle turns in the air, and the cutting power, the power less that
idle power (NaN until a speed has been taught, and while the speed changes: not known,
never a guess). Its charts, on the operator's page: the cutting power with the
monitor's limits (``spindle``), and the spindle's power with the taught idle power
(``spindle-power``: a tool change's run-up and braking, about 15 kW here, would dwarf a
cut of a few hundred watts on one chart). It also says which tool, line and program
the CNC is at (the identities), the status strip's ``tool``, ``program``, ``line``.

The process monitor (:class:`estimators.monitoring.process.ProcessMonitor`, seed 003's
teach-in monitor of the issue-21 part) watches the cutting power, taught per (tool,
program, block) as industrial monitors teach limits on spindle power: a block's
execution is the samples between two changes of the CNC's line; the spindle angle is
the integral of the measured speed. Its mean over a revolution and its limits (the
taught band, the extreme limit) are drawn on the spindle's chart; its alarms are
events (breakage: the revolution's pattern changed; collision: power over the extreme
limit; missing tool: the mean under the band), with the block's tool, program and line
(the part is not in the trace: -1). While the spindle's speed changes (and for the idle
teacher's hold time after) the power holds the rotor's acceleration, whose inertia the
description does not give: the monitor reads no cut there. It says ``teaching`` until
every block it has seen has been taught ``teach_parts`` times, then ``watching``. The
knobs ``teach_parts`` and ``band_factor`` set it; a change of either teaches again.
Where the CNC says a block cannot cut (:class:`server.pipeline.block_motion.CanCut`: from
the program's text where the source holds it, else from the axes' commanded feed) only
the collision detector watches it; the status says from what (``cutting_from``).

It runs on a source that describes a spindle with ``speed`` and ``power`` (the machining
centre, :mod:`server.pipeline.centre_source`, or the same machine over a broker); the
factory builds it only for such a source, so the stage's scenarios stream what they did.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from common.errors import ParameterError
from common.event_kinds import EventKind
from common.machine_description import MachineDescription
from estimators.monitoring.process import Alarm, MonitorParams, ProcessMonitor
from estimators.monitoring.spindle_power import IdlePower, IdlePowerParams, IdlePowerState
from server.pipeline.block_motion import CanCut
from server.pipeline.estimates_out import StatusStrip
from server.pipeline.machine_view import MachineView
from server.pipeline.part import (
    Block,
    Channel,
    Chart,
    LivePart,
    Outputs,
    Setup,
    Verdict,
    column_or,
    diff_from,
    nan_to_num,
    needs_signals,
)
from server.records.monitor_events import DEFAULT_ACTIONS, MonitorEvent

__all__ = ["POWER", "SPINDLE", "SpindlePart", "SpindlePartState"]

SPINDLE = Chart(
    "spindle",
    "Spindle: cutting power (the power less the idle taught in the air; not known while "
    "the speed changes) and the monitor's taught limits",
    page="operator",
    order=5,
    window_s=30.0,
    wide=True,
    markers=True,
)
POWER = Chart(
    "spindle-power",
    "Spindle power: measured (the CNC's) and idle, taught in the air at each speed",
    page="operator",
    order=6,
    window_s=30.0,
    wide=True,
)


_BAND = "#009e73"
#: the monitor's statistic's unit per detector
_UNITS = {"breakage": "1", "collision": "W", "missing_tool": "W"}


@dataclass
class SpindlePartState:
    """The idle power taught so far (per speed bin), the identities last seen, the
    spindle's angle, and the monitor's taught tables and running sums."""

    idle: IdlePowerState
    tool: int = 0
    line: int = 0
    psi: float = 0.0
    last_rpm: float = math.nan
    steady_s: float = 0.0
    teaching: bool = True
    monitor: dict[str, np.ndarray] = field(default_factory=dict)
    params: tuple[int, float] = (5, 4.0)


class SpindlePart(LivePart):
    """The spindle's idle and cutting power (module docstring).

    Parameters
    ----------
    description
        The machine's description (its spindle's ``speed`` and ``power`` columns, the
        identities' columns).
    program
        The part program's name the source runs ("": not known).
    lines
        Per G-code line, whether the program lets it cut
        (:func:`server.pipeline.block_motion.cutting_lines`), where the source holds the
        program's text; else the commanded feed says it.
    """

    name = "spindle"
    charts = (SPINDLE, POWER)
    channels = (
        *POWER.series(
            Channel(
                "spindle_power",
                "W",
                "spindle power (the CNC's)",
                "spindle",
                color="#9aa0a6",
                width=1.0,
                legend="power [W]",
            ),
            Channel(
                "spindle_idle",
                "W",
                "idle power taught in the air at this speed",
                "spindle",
                color="#009e73",
                width=1.4,
                legend="idle, taught [W]",
            ),
        ),
        *SPINDLE.series(
            Channel(
                "spindle_cut",
                "W",
                "cutting power: the power less the idle power",
                "spindle",
                color="#0072b2",
                width=2.0,
                legend="cutting power [W]",
            ),
            Channel(
                "spindle_mean",
                "W",
                "cutting power, mean over a revolution (monitored)",
                "spindle",
                color="#000000",
                width=1.6,
                legend="mean over a revolution [W]",
            ),
            Channel(
                "spindle_upper",
                "W",
                "taught upper band of the mean",
                "spindle",
                color=_BAND,
                width=1.2,
                fill_to="spindle_lower",
                legend="taught band [W]",
            ),
            Channel(
                "spindle_lower",
                "W",
                "taught lower band of the mean",
                "spindle",
                color=_BAND,
                width=1.2,
                legend="taught lower [W]",
            ),
            Channel(
                "spindle_extreme",
                "W",
                "extreme limit of the cutting power",
                "spindle",
                color="#7b3294",
                width=1.6,
                dash=(8.0, 5.0),
                legend="extreme limit [W]",
            ),
        ),
        Channel("spindle_speed", "rpm", "spindle speed (the CNC's actual value)", "spindle"),
    )

    def __init__(
        self,
        description: MachineDescription,
        program: str = "",
        lines: Mapping[int, bool] | None = None,
    ) -> None:
        sp = description.spindle
        sig = sp.signals if sp is not None else {}
        self._speed = sig.get("speed", "")
        self._power = sig.get("power", "")
        ids = description.identities
        self._tool = ids.get("tool", "")
        self._line = ids.get("line", "")
        self.program = program
        self.can_cut = CanCut(description, lines)
        self.sample_time = float(description.sample_time)
        self.idle = IdlePower(IdlePowerParams(sample_time=self.sample_time))
        self.monitor = ProcessMonitor(MonitorParams(sample_time=self.sample_time))
        self.st = SpindlePartState(self.idle.initial_state(), monitor=self.monitor.initial_state())

    def configure(self, setup: Setup) -> None:
        """The monitor's knobs (teach parts, band factor): a change teaches again."""
        k = setup.knobs
        want = (int(float(k["teach_parts"])), float(k["band_factor"]))
        if want == self.st.params and self.monitor.params.teach_parts == want[0]:
            return
        self.monitor = ProcessMonitor(
            MonitorParams(sample_time=self.sample_time, teach_parts=want[0], band_factor=want[1])
        )
        self.st.monitor = self.monitor.initial_state()
        self.st.params = want
        self.st.teaching = True

    def requires(self, machine: MachineView) -> Verdict:
        return needs_signals(
            machine, "spindle.speed", "spindle.power", what="the spindle's cutting power"
        )

    def step(self, block: Block) -> Outputs:
        cols = block.source.columns or {}
        if self._speed not in cols or self._power not in cols:
            nan = block.held(math.nan)
            return {c.name: nan for c in self.channels}, []
        rpm, p = cols[self._speed], cols[self._power]
        self.st.idle, rec = self.idle.step(self.st.idle, rpm, p)
        mon, events = self._watch(block, cols, rpm, rec.cutting)
        return {
            "spindle_power": np.asarray(p, dtype=np.float64),
            "spindle_idle": rec.idle,
            "spindle_speed": np.asarray(rpm, dtype=np.float64),
            **mon,  # the cutting power (where the speed is steady) and the monitor's
        }, events

    def _watch(
        self, block: Block, cols: Any, rpm: Any, cut: Any
    ) -> tuple[dict[str, np.ndarray], list[MonitorEvent]]:
        """The monitor over the block, block execution by block execution (a change of
        the CNC's line starts one); its channels and events."""
        n = block.n
        w = nan_to_num(np.asarray(rpm, dtype=np.float64)) * (math.pi / 30.0)
        psi = np.mod(self.st.psi + np.cumsum(w) * self.sample_time, 2.0 * math.pi)
        self.st.psi = float(psi[-1]) if n else self.st.psi
        steady = self._steady(rpm)
        f = np.where(np.isfinite(cut) & steady, np.asarray(cut, dtype=np.float64), 0.0)
        tool = np.asarray(column_or(cols, self._tool, n, 0.0), dtype=np.float64)
        line = np.asarray(column_or(cols, self._line, n, 0.0), dtype=np.float64)
        over = np.asarray(column_or(cols, "override", n, 1.0), dtype=np.float64)
        out = {"spindle_cut": np.where(steady, np.asarray(cut, dtype=np.float64), math.nan)}
        out |= {k: np.full(n, math.nan) for k in ("spindle_mean", "spindle_upper",
                                                 "spindle_lower", "spindle_extreme")}  # fmt: skip
        events: list[MonitorEvent] = []
        cuts = np.flatnonzero(line[1:] != line[:-1]) + 1
        for a, b in zip([0, *cuts], [*cuts, n], strict=True):
            ln, tl = int(line[a]), int(tool[a])
            new = ln != self.st.line
            self.st.line, self.st.tool = ln, tl
            ovr = float(over[a]) if math.isfinite(over[a]) and 0.0 < over[a] <= 3.0 else 1.0
            can_cut = self.can_cut(cols, ln, a, b, new)
            if not self.monitor.has_room(self.st.monitor, tl, self.program, ln):
                # more blocks than the monitor's segments: this one is not watched (NaN)
                self.monitor.end_block(self.st.monitor)
                continue
            m = self.monitor.step(self.st.monitor, f[a:b], np.zeros(b - a), psi[a:b], tool=tl,
                                  program=self.program, line=ln, new_block=new,
                                  override=ovr, cutting=can_cut)  # fmt: skip
            self.st.teaching = bool(m.teaching)
            for k, v in (("spindle_mean", m.f_mean), ("spindle_upper", m.upper),
                         ("spindle_lower", m.lower), ("spindle_extreme", m.extreme)):  # fmt: skip
                out[k][a:b] = v
            k_first = int(self.st.monitor["samples"][0]) - (b - a)  # the segment's first
            for al in m.alarms:
                j = a + min(max(al.sample - k_first, 0), b - a - 1)
                events.append(self._event(al, float(block.t[j])))
        return out, events

    def _steady(self, rpm: Any) -> np.ndarray:
        """Samples where the spindle speed has been steady for the idle teacher's hold
        time: elsewhere the power holds the rotor's acceleration (its inertia is not in
        the description), which the monitor must not read as a cut (it reads 0 there: a
        collision during a spindle ramp is not seen)."""
        pr = self.idle.params
        r = nan_to_num(np.asarray(rpm, dtype=np.float64))
        prev = self.st.last_rpm if math.isfinite(self.st.last_rpm) else (r[0] if len(r) else 0.0)
        d = np.abs(diff_from(r, prev)) / self.sample_time
        if len(r):
            self.st.last_rpm = float(r[-1])
        k = np.arange(len(r))
        last_bad = np.maximum.accumulate(np.where(d > pr.steady_rpm_per_s, k, -1))
        since = np.where(last_bad >= 0, (k - last_bad) * self.sample_time,
                         self.st.steady_s + (k + 1) * self.sample_time)  # fmt: skip
        if len(r):
            self.st.steady_s = float(since[-1])
        return np.asarray(since >= pr.hold_s)

    def _event(self, a: Alarm, t: float) -> MonitorEvent:
        """An alarm as an event, in an operator's words (the spindle's cutting power)."""
        kind = EventKind(a.detector)
        where = f"T{a.tool} at N{a.line} (program {a.program})"
        if kind == EventKind.BREAKAGE:
            what = (f"the once-per-revolution pattern of the spindle's cutting power changed "
                    f"by {a.value:.2f} of its mean (limit {a.limit:.2f})")  # fmt: skip
            msg = f"Tool breakage suspected on {where}: {what}."
        elif kind == EventKind.COLLISION:
            msg = (f"Collision or overload on {where}: cutting power {a.value:.0f} W over the "
                   f"extreme limit {a.limit:.0f} W.")  # fmt: skip
        else:
            msg = (f"Missing or broken-off tool on {where}: mean cutting power {a.value:.0f} W "
                   f"under the lower limit {a.limit:.0f} W.")  # fmt: skip
        return MonitorEvent(kind=kind, action=DEFAULT_ACTIONS[kind], t=t, tool=a.tool,
                            program=a.program, line=a.line, part=-1, value=a.value,
                            limit=a.limit, unit=_UNITS[str(a.detector)], message=msg)  # fmt: skip

    def status(self) -> StatusStrip:
        """The monitor's state (teaching, watching) and the CNC's tool, program and line
        (the identities the trace carries)."""
        return {
            "state": "teaching" if self.st.teaching else "watching",
            "tool": self.st.tool,
            "program": self.program,
            "line": self.st.line,
            "cutting_from": self.can_cut.source,
        }

    def state(self) -> SpindlePartState:
        return self.st

    def restore(self, state: object) -> None:
        if not isinstance(state, SpindlePartState):
            raise ParameterError("state.parts.spindle", "a SpindlePartState", type(state).__name__)
        self.st = state
