"""The spindle's cutting power as a live part: its power less the idle power taught in air.

:class:`SpindlePart` (issue 31 phase 2, step b) reads a described machine's spindle
signals (its ``speed`` [rpm] and ``power`` [W], by the machine description's column
names) and runs :class:`estimators.spindle_power.IdlePower`: the idle power taught per
speed while the spindle turns in the air, and the cutting power, the power less that
idle power (NaN until a speed has been taught: not known, never a guess). Its chart, on
the operator's page, is the spindle's power, the taught idle power and the cutting
power. It also says which tool, line and program the CNC is at (the identities), the
status strip's ``tool``, ``program``, ``line``.

Not yet here (issue 31, step b's second half): the process monitor taught per (tool,
program, block) on the cutting power, and its limits on this chart.

It runs on a source that describes a spindle with ``speed`` and ``power`` (the machining
centre, :mod:`server.pipeline.centre_source`, or the same machine over a broker); the
factory builds it only for such a source, so the stage's scenarios stream what they did.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from common.errors import ParameterError
from common.machine_description import MachineDescription
from estimators.spindle_power import IdlePower, IdlePowerParams, IdlePowerState
from server.pipeline.machine_view import MachineView
from server.pipeline.part import (
    Block,
    Channel,
    Chart,
    LivePart,
    Outputs,
    Verdict,
    needs_signals,
)

__all__ = ["SPINDLE", "SpindlePart", "SpindlePartState"]

SPINDLE = Chart(
    "spindle",
    "Spindle power: measured, idle (taught in the air at each speed) and cutting power",
    page="operator",
    order=5,
    window_s=30.0,
    wide=True,
    markers=True,
)


@dataclass
class SpindlePartState:
    """The idle power taught so far (per speed bin) and the identities last seen."""

    idle: IdlePowerState
    tool: int = 0
    line: int = 0


class SpindlePart(LivePart):
    """The spindle's idle and cutting power (module docstring).

    Parameters
    ----------
    description
        The machine's description (its spindle's ``speed`` and ``power`` columns, the
        identities' columns).
    program
        The part program's name the source runs ("": not known).
    """

    name = "spindle"
    charts = (SPINDLE,)
    channels = (
        *SPINDLE.series(
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
            Channel(
                "spindle_cut",
                "W",
                "cutting power: the power less the idle power",
                "spindle",
                color="#0072b2",
                width=2.0,
                legend="cutting power [W]",
            ),
        ),
        Channel("spindle_speed", "rpm", "spindle speed (the CNC's actual value)", "spindle"),
    )

    def __init__(self, description: MachineDescription, program: str = "") -> None:
        sp = description.spindle
        sig = sp.signals if sp is not None else {}
        self._speed = sig.get("speed", "")
        self._power = sig.get("power", "")
        ids = description.identities
        self._tool = ids.get("tool", "")
        self._line = ids.get("line", "")
        self.program = program
        self.idle = IdlePower(IdlePowerParams(sample_time=description.sample_time))
        self.st = SpindlePartState(self.idle.initial_state())

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
        for attr, col in (("tool", self._tool), ("line", self._line)):
            v = cols.get(col)
            if v is not None and len(v) and math.isfinite(float(v[-1])):
                setattr(self.st, attr, int(v[-1]))
        return {
            "spindle_power": np.asarray(p, dtype=np.float64),
            "spindle_idle": rec.idle,
            "spindle_cut": rec.cutting,
            "spindle_speed": np.asarray(rpm, dtype=np.float64),
        }, []

    def status(self) -> dict[str, object]:
        """The CNC's tool, program and line (the identities the trace carries)."""
        return {"tool": self.st.tool, "program": self.program, "line": self.st.line}

    def state(self) -> SpindlePartState:
        return self.st

    def restore(self, state: object) -> None:
        if not isinstance(state, SpindlePartState):
            raise ParameterError("state.parts.spindle", "a SpindlePartState", type(state).__name__)
        self.st = state
