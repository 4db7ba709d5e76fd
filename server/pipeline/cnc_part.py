"""The spindle as a CNC's OPC UA server reports it, as a live part.

For the OPC UA source (issue 33), whose blocks carry every signal of its machine
description by node id (``SourceBlock.columns``), :class:`CncPart` streams the spindle's
signals as the CNC gives them, in the description's units: ``spindle.speed`` [rpm],
``spindle.speed_cmd``, ``spindle.power`` [W], ``spindle.torque`` [N m],
``spindle.current`` [A], ``spindle.load`` [%], on the operator's page. The axes are the
``axes`` part's (:mod:`server.pipeline.axis_part`).
"""

from __future__ import annotations

import math

import numpy as np

from common.arrays import F64
from common.machine_description import MachineDescription
from server.pipeline.part import Block, Channel, Chart, LivePart, Outputs

__all__ = ["SPINDLE", "CncPart"]

SPINDLE = Chart("cnc-spindle", "Spindle (as the CNC reports it)", page="operator", order=20)
_LABELS = {"speed": "spindle speed", "speed_cmd": "commanded spindle speed",
           "power": "spindle power", "torque": "spindle torque", "current": "spindle current",
           "load": "spindle load"}  # fmt: skip
#: the signals drawn on the chart (the others are streamed, not drawn: other units)
_DRAWN = ("speed", "speed_cmd")


class CncPart(LivePart):
    """The described machine's spindle signals (module docstring)."""

    name = "cnc"

    def __init__(self, machine: MachineDescription) -> None:
        sp = machine.spindle
        self.sources = {} if sp is None else dict(sp.signals)
        chans = {
            r: Channel(f"spindle.{r}", sp.unit(r), _LABELS[r], f"spindle.{r}", legend=_LABELS[r])
            for r in self.sources
            if sp is not None
        }
        drawn = SPINDLE.series(*(chans[r] for r in _DRAWN if r in chans))
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
