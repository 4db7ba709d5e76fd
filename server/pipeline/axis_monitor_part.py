"""The process monitor on the axes' process force, taught per (tool, program, block).

:class:`AxisMonitorPart` (issue 31 item 2) runs the spindle part's detector
(:class:`estimators.monitoring.process.ProcessMonitor`, seed 003's teach-in monitor of the
issue-21 part) on each axis' process force ``<axis>.F`` that the ``axes`` part
estimates (:mod:`server.pipeline.axis_part`: the effort less the rigid model identified
live), one monitor per axis: the magnitude of the force, its mean over a spindle
revolution (the angle is the integral of the CNC's spindle speed) and its
once-per-revolution pattern, taught per (tool, program, block) over ``teach_parts``
executions at 100 % override, a block's execution being the samples between two
changes of the CNC's line (as the spindle part's). Its alarms are events naming the
axis (breakage: the revolution's pattern of that axis' force changed; collision: the
force over the extreme limit; missing tool: the mean under the band), with the block's
tool, program and line.

What it can see at a CNC's trace rate: the axes' force passes what the identifier's
parallel filter passes (at 500 Hz, (w/(s+w))^4 at 50 Hz: ~22 Hz), so the
once-per-revolution pattern of a spindle at 3,000-10,000 rpm (50-167 Hz) is not in it
and the breakage detector reads the filter's remnant; the mean force (a collision's
feed, a missing tool) is. An axis at rest carries the cut's force (its drive holds it);
a force the estimate has wrong in the same way every part (an acceleration step's
sampling, X's rigid model of a two-inertia axis) is taught with the block.

**Where the tool cuts.** In the air an axis' process force is its model's error (the
acceleration steps' sampling: hundreds of newtons on Z at a rapid's start), which a
monitor taught per block would take for a cut; so the force is read as 0 where the
spindle's cutting power (the ``spindle`` part's) says the tool is in the air (known,
and under :data:`CUT_W`), and as estimated elsewhere (in a cut, and where the cutting
power is not known but the spindle's command is steady: its speed dips under a
collision's overload). Where the command changed in the last :data:`CMD_HOLD_S` (a tool
change, a run-up) or is 0 the force is read as 0 too. A missing tool is then seen
through the spindle's power as well (no cut: a mean of 0 under the band).

Where the CNC says a block cannot cut (:class:`server.pipeline.block_motion.CanCut`: from
the program's text where the source holds it, else from the axes' commanded feed) only
the collision detector watches it (``ProcessMonitor.step(..., cutting=False)``).

It runs where the ``axes`` part runs and the description gives the spindle's speed and
the CNC's line (else it is not built, or says why it cannot run). The knobs
``teach_parts`` and ``band_factor`` set it, as the spindle part's; a change teaches again.
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
    nan_channels,
    nan_to_num,
    needs_signals,
)
from server.records.monitor_events import DEFAULT_ACTIONS, MonitorEvent

__all__ = ["AxisMonitorPart", "AxisMonitorState", "monitored_axes"]

_BAND = "#009e73"
#: the spindle's cutting power above which the tool cuts [W]: the idle taught in the air
#: is within a few watts (docs/machining-centre.md: -2.3 to +2.4 W per block), the default
#: part's lightest cut takes 450 W
CUT_W = 50.0
#: after a change of the spindle's commanded speed, the seconds its cutting power is not
#: known for a run-up's sake, not a cut's (a tool change; the run-up to 10,000 rpm takes
#: 0.7 s at the drive's 1500 rad/s^2 ramp, the idle teacher then holds 0.1 s)
CMD_HOLD_S = 2.0
#: a taught bin counts as cutting above this mean force [N] (the monitor's
#: ``min_cut_force``): the axes' force error on the centre's 500 Hz trace is 10-40 N rms
#: away from the acceleration steps (docs/machining-centre.md); Z's 20-40 N in the
#: default part is under it (at 5 N, its missing-tool detector raised 6 false alarms in
#: 3 seeds x 480 s, X and Y none)
MIN_CUT_N = 50.0
#: the monitor's statistic's unit per detector
_UNITS = {"breakage": "1", "collision": "N", "missing_tool": "N"}


@dataclass
class AxisMonitorState:
    """Per axis the monitor's taught tables and running sums; the identities last seen,
    the spindle's angle, the knobs the monitors were made with."""

    monitors: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    tool: int = 0
    line: int = 0
    psi: float = 0.0
    teaching: bool = True
    params: tuple[int, float] = (5, 4.0)
    last_cmd: float = math.nan
    cmd_steady_s: float = 0.0


def _declare(axes: tuple[str, ...]) -> tuple[tuple[Chart, ...], tuple[Channel, ...]]:
    charts: list[Chart] = []
    chans: list[Channel] = []
    for i, a in enumerate(axes):
        c = Chart(
            f"axis-{a}-monitor",
            f"{a}: process force (magnitude), its mean over a spindle revolution and the "
            "monitor's limits taught per tool, program and block",
            page="operator",
            order=50 + i,
            window_s=30.0,
            markers=True,
        )
        charts.append(c)
        chans += c.series(
            Channel(
                f"{a}.F_mean",
                "N",
                f"{a} process force, mean over a revolution (monitored)",
                f"{a}.monitor",
                color="#000000",
                width=1.6,
                legend="mean over a revolution [N]",
            ),
            Channel(
                f"{a}.F_upper",
                "N",
                f"{a} taught upper band of the mean",
                f"{a}.monitor",
                color=_BAND,
                width=1.2,
                fill_to=f"{a}.F_lower",
                legend="taught band [N]",
            ),
            Channel(
                f"{a}.F_lower",
                "N",
                f"{a} taught lower band of the mean",
                f"{a}.monitor",
                color=_BAND,
                width=1.2,
                legend="taught lower [N]",
            ),
            Channel(
                f"{a}.F_extreme",
                "N",
                f"{a} extreme limit of the process force",
                f"{a}.monitor",
                color="#7b3294",
                width=1.6,
                dash=(8.0, 5.0),
                legend="extreme limit [N]",
            ),
        )
    return tuple(charts), tuple(chans)


def monitored_axes(description: MachineDescription) -> tuple[str, ...]:
    """The axes whose process force is a force in N: a position, and the effort in N or a
    current with its force constant (an effort left in A, as a CNC's export without the
    motor's data, has no force to set a limit in newtons on)."""
    return tuple(
        a.name
        for a in description.axes
        if "q_m" in a.signals
        and a.effort_unit == "N"
        and ("tau_m" in a.signals or ("i_m" in a.signals and a.K_t is not None))
    )


class AxisMonitorPart(LivePart):
    """The process monitor on every axis' process force (module docstring).

    Parameters
    ----------
    description
        The machine's description (its axes, the spindle's ``speed``, the identities).
    program
        The part program's name the source runs ("": not known).
    lines
        Per G-code line, whether the program lets it cut
        (:func:`server.pipeline.block_motion.cutting_lines`), where the source holds the
        program's text; else the commanded feed says it.
    """

    name = "axis_monitor"
    needs = ("axes", "spindle")

    def __init__(
        self,
        description: MachineDescription,
        program: str = "",
        lines: Mapping[int, bool] | None = None,
    ) -> None:
        self.axes = monitored_axes(description)
        self.can_cut = CanCut(description, lines)
        sp = description.spindle
        self._speed = (sp.signals if sp is not None else {}).get("speed", "")
        self._speed_cmd = (sp.signals if sp is not None else {}).get("speed_cmd", "")
        ids = description.identities
        self._tool = ids.get("tool", "")
        self._line = ids.get("line", "")
        self.program = program
        self.sample_time = float(description.sample_time)
        self.charts, self.channels = _declare(self.axes)
        self.monitor = ProcessMonitor(
            MonitorParams(sample_time=self.sample_time, min_cut_force=MIN_CUT_N)
        )
        self.st = AxisMonitorState({a: self.monitor.initial_state() for a in self.axes})

    def configure(self, setup: Setup) -> None:
        """The monitor's knobs (teach parts, band factor): a change teaches again."""
        k = setup.knobs
        want = (int(float(k["teach_parts"])), float(k["band_factor"]))
        if want == self.st.params and self.monitor.params.teach_parts == want[0]:
            return
        self.monitor = ProcessMonitor(
            MonitorParams(
                sample_time=self.sample_time,
                teach_parts=want[0],
                band_factor=want[1],
                min_cut_force=MIN_CUT_N,
            )
        )
        self.st.monitors = {a: self.monitor.initial_state() for a in self.axes}
        self.st.params = want
        self.st.teaching = True

    def requires(self, machine: MachineView) -> Verdict:
        return needs_signals(
            machine, "spindle.speed", what="the spindle's angle (the revolution's pattern)"
        )

    def step(self, block: Block) -> Outputs:
        n = block.n
        cols = block.source.columns or {}
        out = nan_channels(self.channels, n)
        if self._speed not in cols or self._line not in cols:
            return out, []
        rpm = nan_to_num(np.asarray(cols[self._speed], dtype=np.float64))
        psi = np.mod(self.st.psi + np.cumsum(rpm * (math.pi / 30.0)) * self.sample_time,
                     2.0 * math.pi)  # fmt: skip
        if n:
            self.st.psi = float(psi[-1])
        tool = np.asarray(column_or(cols, self._tool, n, 0.0), dtype=np.float64)
        line = np.asarray(cols[self._line], dtype=np.float64)
        over = np.asarray(column_or(cols, "override", n, 1.0), dtype=np.float64)
        force = {a: np.asarray(column_or(block.outputs, f"{a}.F", n, math.nan)) for a in self.axes}
        cut = np.asarray(column_or(block.outputs, "spindle_cut", n, math.nan))
        with np.errstate(invalid="ignore"):
            air = np.isfinite(cut) & (cut <= CUT_W)  # known to be in the air
        air |= ~np.isfinite(cut) & self._commanded_change(cols, n)
        zeros = np.zeros(n)
        events: list[MonitorEvent] = []
        cuts = np.flatnonzero(line[1:] != line[:-1]) + 1
        teaching = False
        for a0, b0 in zip([0, *cuts], [*cuts, n], strict=True):
            ln, tl = int(line[a0]), int(tool[a0])
            new = ln != self.st.line
            self.st.line, self.st.tool = ln, tl
            ovr = float(over[a0]) if math.isfinite(over[a0]) and 0.0 < over[a0] <= 3.0 else 1.0
            can_cut = self.can_cut(cols, ln, a0, b0, new)
            for ax in self.axes:
                st = self.st.monitors[ax]
                if not self.monitor.has_room(st, tl, self.program, ln):
                    # more blocks than the monitor's segments: this one is not watched (NaN)
                    self.monitor.end_block(st)
                    continue
                # read but where the tool is known to be in the air (not known yet: 0)
                f = np.where(air[a0:b0], 0.0, nan_to_num(force[ax][a0:b0]))
                m = self.monitor.step(st, f, zeros[a0:b0], psi[a0:b0], tool=tl,
                                      program=self.program, line=ln, new_block=new,
                                      override=ovr, cutting=can_cut)  # fmt: skip
                teaching |= bool(m.teaching)
                for k, v in (("F_mean", m.f_mean), ("F_upper", m.upper),
                             ("F_lower", m.lower), ("F_extreme", m.extreme)):  # fmt: skip
                    out[f"{ax}.{k}"][a0:b0] = v
                k_first = int(st["samples"][0]) - (b0 - a0)
                for al in m.alarms:
                    j = a0 + min(max(al.sample - k_first, 0), b0 - a0 - 1)
                    events.append(self._event(ax, al, float(block.t[j])))
        if n:
            self.st.teaching = teaching
        return out, events

    def _commanded_change(self, cols: Any, n: int) -> np.ndarray:
        """Samples within :data:`CMD_HOLD_S` of a change of the spindle's commanded speed
        (or where it is 0): a tool change, a run-up, no cut (no command: none)."""
        if self._speed_cmd not in cols:
            return np.zeros(n, dtype=bool)
        c = nan_to_num(np.asarray(cols[self._speed_cmd], dtype=np.float64))
        prev = self.st.last_cmd
        changed = np.abs(diff_from(c, c[0] if math.isnan(prev) else prev)) > 0.0
        k = np.arange(n)
        last = np.maximum.accumulate(np.where(changed, k, -1))
        since = np.where(last >= 0, (k - last) * self.sample_time,
                         self.st.cmd_steady_s + (k + 1) * self.sample_time)  # fmt: skip
        if n:
            self.st.last_cmd = float(c[-1])
            self.st.cmd_steady_s = float(since[-1])
        return np.asarray((since < CMD_HOLD_S) | (c == 0.0))

    def _event(self, axis: str, a: Alarm, t: float) -> MonitorEvent:
        """An alarm as an event, in an operator's words, naming the axis."""
        kind = EventKind(a.detector)
        where = f"T{a.tool} at N{a.line} (program {a.program})"
        if kind == EventKind.BREAKAGE:
            msg = (f"Tool breakage suspected on {where}, axis {axis}: the once-per-revolution "
                   f"pattern of the {axis} axis' process force changed by {a.value:.2f} of "
                   f"its mean (limit {a.limit:.2f}).")  # fmt: skip
        elif kind == EventKind.COLLISION:
            msg = (f"Collision or overload on {where}, axis {axis}: the {axis} axis' process "
                   f"force {a.value:.0f} N over the extreme limit {a.limit:.0f} N.")  # fmt: skip
        else:
            msg = (f"Missing or broken-off tool on {where}, axis {axis}: the {axis} axis' "
                   f"mean process force {a.value:.0f} N under the lower limit "
                   f"{a.limit:.0f} N.")  # fmt: skip
        return MonitorEvent(kind=kind, action=DEFAULT_ACTIONS[kind], t=t, tool=a.tool,
                            program=a.program, line=a.line, part=-1, value=a.value,
                            limit=a.limit, unit=_UNITS[str(a.detector)], message=msg)  # fmt: skip

    def status(self) -> StatusStrip:
        return {"axes_cutting_from": self.can_cut.source}

    def state(self) -> AxisMonitorState:
        return self.st

    def restore(self, state: object) -> None:
        if not isinstance(state, AxisMonitorState):
            raise ParameterError(
                "state.parts.axis_monitor", "an AxisMonitorState", type(state).__name__
            )
        self.st = state
