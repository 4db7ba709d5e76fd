"""The machining centre, simulated and exported at its CNC's trace rate, as a measurement source.

:class:`CentreSource` (issue 31 phase 2, step a) satisfies
:class:`server.pipeline.sources.MeasurementSource`: it runs
:class:`machine.centre.sim.MachiningCentre` (its part program, tools, events) at the
simulation's 10 kHz and hands out the CNC's trace (:mod:`machine.centre.trace`, 500 Hz
point samples by default) with the machine description
(:func:`machine.centre.signals.description`) as ``description``: what a CNC's edge
device would send, and nothing else. So the parts see it exactly as they would see the
same machine over a broker (:mod:`server.pipeline.centre_feed`).

Each block's :class:`~server.pipeline.sources.SourceBlock` carries

- ``meas``: the X axis (two-inertia, linear scale) as the one-axis Measurements the
  stage's observers read: ``q_m``, ``q_l`` [m], ``i_m`` [A], ``tau_m`` = ``K_t i_m``
  [N] (the force constant known from the motor data), ``f_ext`` NaN (no reference);
- ``columns``: every signal of the trace by its column name (``X_q_m``, ``Y_i_m``,
  ``S_power``, ``tool``, ``line``, ``override``...), the description's names: what the
  described-machine parts read (the axes' identification, the spindle's power).

It carries no :class:`machine.stage.Truth` (``has_truth`` False: the centre's truth is
not the stage's); the simulator's truth of the last block (process forces, cutting
torque, flank wear, the injected events) is kept in :attr:`CentreSource.truth` for
display and scoring, never handed to a part. The scenario's knobs do not drive it
(``knobs_apply`` False); the loop paces it (``paced``). Its description gives no
nominal two-inertia parameters (a CNC does not hand them out): the stage's observers say
so and do not run (:attr:`server.pipeline.machine_view.AxisView.prior`).
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from common.arrays import F64
from common.machine_description import MachineDescription
from machine.centre import signals
from machine.centre.program import program_variant
from machine.centre.sim import CentreState, MachiningCentre
from machine.centre.trace import CncTrace, TraceParams, TraceState
from machine.process import EventTruth
from machine.stage import Measurements
from machine.stage_params import StageParams, preset
from server.pipeline.sources import Scheduled, SourceBlock, TruthSummary, empty_measurements

__all__ = ["CENTRE_RATE_HZ", "CentreSource"]

#: the trace rate the live default runs at [Hz] (a CNC's position-control cycle, 2 ms)
CENTRE_RATE_HZ = 500.0


class CentreSource:
    """The machining centre's CNC trace, block by block (see the module docstring).

    Parameters
    ----------
    seed
        Seed of the simulation (noise, overrides, depths, tool lives, runouts).
    rate_hz, mode
        The trace (:class:`machine.centre.trace.TraceParams`).
    index
        Which program variant the machine runs (``O{2001 + index}``,
        :func:`machine.centre.program.program_variant`).
    """

    name = "centre"
    kind = "two_inertia"
    has_truth = False
    knobs_apply = False
    paced = True
    finished = False

    def __init__(
        self, seed: int = 0, rate_hz: float = CENTRE_RATE_HZ, mode: str = "sample", index: int = 0
    ) -> None:
        self.seed = int(seed)
        self.machine = MachiningCentre(program=program_variant(index))
        self.trace = CncTrace(TraceParams(rate_hz, mode), self.machine.sample_time)
        self.rate_hz = float(rate_hz)
        self.description: MachineDescription = signals.description(self.machine.params, rate_hz)
        x = self.machine.params.axes[0]
        self._x = x.name
        self._k_t = float(x.force_constant)
        self._encoder = float(x.encoder_quantum)
        #: the simulator's truth of the last block, by column (``true_*``), and the
        #: injected events placed so far: for display and scoring, never for a part
        self.truth: dict[str, F64] = {}
        self.events: list[EventTruth] = []
        self._state: CentreState = self.machine.initial_state(seed=self.seed)
        self._tstate: TraceState = self.trace.initial_state()
        self._k = 0

    # -- MeasurementSource -------------------------------------------------------------
    @property
    def sample_time(self) -> float:
        return 1.0 / self.rate_hz

    @property
    def nominal(self) -> StageParams:
        """Seed 000's stage: the part that builds observers needs some; the description's
        axes without a nominal say they are not this machine's (the stage part does not
        run)."""
        return preset("seed000")

    @property
    def encoder_resolution(self) -> float:
        return self._encoder

    @property
    def t(self) -> float:
        return self._k * self.sample_time

    @property
    def program(self) -> str:
        return self.machine.program.name

    def step(self, n: int) -> SourceBlock:
        n = max(int(n), 0)
        if n == 0:
            return SourceBlock(empty_measurements(), columns={})
        self._state, rec = self.machine.step(self._state, n * self.trace.factor)
        self._tstate, tr = self.trace.export(self._tstate, rec)
        self.events += tr.events
        del self.events[:-200]
        cols = signals.columns(tr, self.machine.params, truth=True)
        self.truth = {k: v for k, v in cols.items() if k.startswith("true_")}
        meas_cols = {k: v for k, v in cols.items() if not k.startswith("true_")}
        # the trace's samples on the source's own clock (its cycles are uniform)
        t = np.asarray((self._k + np.arange(tr.n)) * self.sample_time, dtype=np.float64)
        self._k += tr.n
        meas_cols["t"] = t
        x = self._x
        i_m = meas_cols[signals.column(x, "i_m")]
        meas = Measurements(
            t=t,
            i_m=i_m,
            tau_m=self._k_t * i_m,
            q_m=meas_cols[signals.column(x, "q_m")],
            q_l=meas_cols[signals.column(x, "q_l")],
            f_ext=np.full(tr.n, math.nan),
        )
        return SourceBlock(meas, columns=meas_cols)

    def inject(
        self,
        kind: str,
        size: float | None = None,
        at_t: float | None = None,
        at_part: int | None = None,
    ) -> Scheduled:
        """Schedule an event in the centre's part program: ``kind`` one of breakage,
        collision, missing_tool, of ``size`` (default
        :data:`server.pipeline.centre_feed.EVENT_SIZES`: a broken tooth of 0.3 mm, a
        collision at 3x the feed, the tool lost whole), in the middle of the first cut of
        part ``at_part`` (default: the next part). A time (``at_t``) is not offered on
        the centre. Returns what was scheduled.

        Raises
        ------
        ParameterError
            An unknown kind, a size not positive, a time, a part already begun.
        """
        from common.errors import ParameterError
        from machine.process import EVENT_KINDS, ProcessEvent
        from server.pipeline.centre_feed import EVENT_SIZES

        if kind not in EVENT_KINDS:
            raise ParameterError("kind", "one of " + ", ".join(EVENT_KINDS), kind)
        if at_t is not None:
            raise ParameterError("at_t", "none on the machining centre (give at_part)", at_t)
        size = EVENT_SIZES[kind] if size is None else size
        if isinstance(size, bool) or not isinstance(size, int | float) or not size > 0:
            raise ParameterError("size", "a positive size", size)
        first = int(self._state.part) + 1
        part = first if at_part is None else at_part
        if isinstance(part, bool) or not isinstance(part, int) or part < first:
            raise ParameterError("at_part", f"a part number >= {first}", at_part)
        line = next(b.line for b in self.machine.program.blocks if b.cut is not None)
        ev = ProcessEvent(kind, part, line, 0.5, float(size), 0)
        self._state = self.machine.schedule(self._state, ev)
        return {"kind": kind, "size": float(size), "at_part": part, "line": line,
                "where": "the middle of that part's first cut"}  # fmt: skip

    def reconfigure(self, **changes: object) -> None:
        """The knobs do not drive the centre (``knobs_apply`` False): nothing changes."""

    def reset(self) -> None:
        self._state = self.machine.initial_state(seed=self.seed)
        self._tstate = self.trace.initial_state()
        self._k = 0
        self.truth = {}
        self.events = []

    def state(self) -> object:
        return {
            "centre": self._state.copy(),
            "trace": copy.deepcopy(self._tstate),
            "k": self._k,
        }

    def restore(self, state: object) -> None:
        if not isinstance(state, Mapping):
            from common.errors import ParameterError

            raise ParameterError("state.source_state", "a centre source's state", state)
        self._state = state["centre"].copy()
        self._tstate = copy.deepcopy(state["trace"])
        self._k = int(state["k"])

    def truth_summary(self) -> TruthSummary:
        """The simulated machine's truth now: the part, the tool's flank wear, the events."""
        out: TruthSummary = {"program": self.program, "events": len(self.events)}
        for k in ("true_part", "true_vb"):
            v = self.truth.get(k)
            if v is not None and len(v):
                out[k[5:]] = float(v[-1])
        return out

    def status(self) -> dict[str, Any]:
        return {
            "machine": "3-axis machining centre",
            "program": self.program,
            "trace_hz": self.rate_hz,
            "trace_mode": self.trace.params.mode,
        }
