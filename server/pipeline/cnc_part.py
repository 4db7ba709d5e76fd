"""A described machine's own signals as a live part: its spindle, its axes identified.

For a source that hands out every signal of its machine description by source name
(``SourceBlock.columns``: the OPC UA source, issue 33), :class:`CncPart` streams

- the spindle's signals as the CNC gives them (``spindle.speed`` [rpm], ``spindle.power``
  [W], ...), on the operator's page;
- every axis identified live as a rigid axis (:class:`server.pipeline.axis_identification.
  AxisIdentification`, designed from the source's rate): ``<axis>.M``, ``.Fv``, ``.Fc``
  with their 95 % intervals and excitation, and the process force ``<axis>.F``. What
  cannot run at the rate (the mass at 10 Hz without an acceleration) is in
  :meth:`CncPart.status` (``reasons``) and streams NaN.

A discontinuity in the feed (a reconnect, a restart from a checkpoint) restarts the
identifiers' filters and keeps the identified parameters (the machine is the same).
It is built only for a source with a machine description and columns (not the simulated
stage, a replayed log or the broker feed, whose blocks carry no columns).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from common.arrays import F64
from common.machine_description import MachineDescription
from server.pipeline.axis_identification import AxisIdentification
from server.pipeline.part import Block, Channel, Chart, LivePart, Outputs

__all__ = ["SPINDLE", "CncPart"]

SPINDLE = Chart("cnc-spindle", "Spindle (as the CNC reports it)", page="operator", order=20)
_LABELS = {"speed": "spindle speed", "speed_cmd": "commanded spindle speed",
           "power": "spindle power", "torque": "spindle torque", "current": "spindle current",
           "load": "spindle load"}  # fmt: skip


class CncPart(LivePart):
    """The described machine's spindle and axes (module docstring)."""

    name = "cnc"

    def __init__(self, machine: MachineDescription) -> None:
        self.machine = machine
        self.ident = AxisIdentification(machine)
        self._state = self.ident.initial_state()
        sp = machine.spindle
        self.spindle_sources = {} if sp is None else dict(sp.signals)
        spindle = tuple(
            Channel(f"spindle.{r}", sp.unit(r), _LABELS[r], f"spindle.{r}", legend=_LABELS[r])
            for r in self.spindle_sources
            if sp is not None
        )
        charts: list[Chart] = [SPINDLE] if spindle else []
        channels: list[Channel] = list(SPINDLE.series(*spindle)) if spindle else []
        by_axis: dict[str, list[Any]] = {}
        for c in self.ident.channels():
            by_axis.setdefault(c.name.split(".", 1)[0], []).append(c)
        for i, (axis, chans) in enumerate(by_axis.items()):
            chart = Chart(f"cnc-{axis}", f"Axis {axis}: identified friction and mass", order=60 + i)
            force = Chart(f"cnc-{axis}-force", f"Axis {axis}: process force", order=61 + i)
            drawn, plain = [], []
            for c in chans:
                base = c.name.split(".", 1)[1]
                if base in ("M", "Fv", "Fc"):
                    iv = (f"{c.name}_lo", f"{c.name}_hi", f"{c.name}_excited")
                    drawn.append(Channel(c.name, c.unit, c.label, c.group, interval=iv))
                elif base == "F":
                    plain.append(Channel(c.name, c.unit, c.label, c.group))
                else:
                    channels.append(Channel(c.name, c.unit, c.label, c.group))
            charts += [chart, force]
            channels += [*chart.series(*drawn), *force.series(*plain)]
        self.charts = tuple(charts)
        self.channels = tuple(channels)

    def status(self) -> dict[str, object]:
        return {}

    @property
    def reasons(self) -> dict[str, dict[str, str]]:
        """Per axis, what does not run at this rate and why."""
        return self.ident.reasons

    def step(self, block: Block) -> Outputs:
        cols = block.source.columns
        n = block.n
        out: dict[str, F64] = {}
        for r, src in self.spindle_sources.items():
            v = cols.get(src)
            out[f"spindle.{r}"] = np.asarray(v, dtype=np.float64) if v is not None else (
                np.full(n, math.nan))  # fmt: skip
        if block.discontinuity is not None:
            self._state = self.ident.restart_filters(self._state)
        needed = {s for a in self.machine.axes for s in a.signals.values()}
        if not needed <= set(cols):
            out.update({c.name: np.full(n, math.nan) for c in self.ident.channels()})
            return out, []
        self._state, ident = self.ident.step(self._state, block.meas.t, cols)
        out.update(ident)
        return out, []

    def state(self) -> object:
        return self._state

    def restore(self, state: object) -> None:
        if isinstance(state, dict):
            self._state = state
