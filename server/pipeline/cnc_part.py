"""The spindle drive's raw signals as a CNC's OPC UA server reports them, as a live part.

For the OPC UA source (issue 33), whose blocks carry every signal of its machine
description by node id (``SourceBlock.columns``), :class:`CncPart` streams the spindle's
signals the ``spindle`` part (:mod:`server.pipeline.spindle_part`: speed, power and the
cutting power over the taught idle power) does not, as the CNC gives them, in the
description's units: ``spindle.speed_cmd`` [rpm], ``spindle.torque`` [N m],
``spindle.current`` [A], ``spindle.load`` [%]; torque and current drawn on a research
chart. The axes are the ``axes`` part's (:mod:`server.pipeline.axis_part`).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from common.arrays import F64
from common.machine_description import MachineDescription
from server.pipeline.part import Block, Channel, Chart, LivePart, Outputs

__all__ = ["SPINDLE", "CncPart"]

SPINDLE = Chart("cnc-spindle", "Spindle drive as the CNC reports it: torque, current", order=20)
_LABELS = {"speed": "spindle speed", "speed_cmd": "commanded spindle speed",
           "power": "spindle power", "torque": "spindle torque", "current": "spindle current",
           "load": "spindle load"}  # fmt: skip
#: the spindle part's signals (not streamed again here)
_SPINDLE_PART = ("speed", "power")
#: the signals drawn on the chart (the others are streamed, not drawn)
_DRAWN = ("torque", "current")


class CncPart(LivePart):
    """The described machine's spindle signals (module docstring)."""

    name = "cnc"

    def __init__(self, machine: MachineDescription) -> None:
        sp = machine.spindle
        self.sources = {} if sp is None else {
            r: src for r, src in sp.signals.items() if r not in _SPINDLE_PART
        }  # fmt: skip
        chans = {
            r: Channel(f"spindle.{r}", sp.unit(r), _LABELS[r], f"spindle.{r}", legend=_LABELS[r])
            for r in self.sources
            if sp is not None
        }
        drawn = SPINDLE.series(
            *(replace(chans[r], axis="A" if r == "current" else "") for r in _DRAWN if r in chans)
        )
        self.charts = (SPINDLE,) if drawn else ()
        self.channels = (*drawn, *(c for r, c in chans.items() if r not in _DRAWN))

    def step(self, block: Block) -> Outputs:
        cols = block.source.columns
        out: dict[str, F64] = {}
        for r, src in self.sources.items():
            v = cols.get(src)
            out[f"spindle.{r}"] = (
                np.asarray(v, dtype=np.float64) if v is not None else np.full(block.n, math.nan)
            )
        return out, []
