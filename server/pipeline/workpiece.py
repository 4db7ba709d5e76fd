"""The workpiece of the default scenario: a blank losing mass, clamped fresh when used up.

The blank is an inertia of the size of seed 000's added weight; it loses
``removal_rate`` % of its mass per second of machining. The plant's inertia follows in
steps (:data:`REMOVAL_STEP`) applied mid-stroke, and a fresh blank is clamped just before
a reversal (the table at its stroke end), at the last such reversal before the blank is
used up (docs/live-identification.md).

:class:`WorkpiecePart` is the live part (:mod:`server.pipeline.part`): before each block
it advances the removal (a fresh blank: J_L changes, the CNC knows it) and adds the
blank's inertia to the simulated stage's load. It streams no channel of its own (the
stage's ``J_L_true`` shows the mass); it simulates, so it runs with the simulator only.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from common.errors import ParameterError
from machine.stage_params import ADDED_WEIGHT_INERTIA
from server.pipeline.machine_view import MachineView
from server.pipeline.part import (
    Block,
    LivePart,
    Notice,
    Outputs,
    Plan,
    Verdict,
    needs_simulator,
)

WORKPIECE_INERTIA = ADDED_WEIGHT_INERTIA  # a blank as heavy as seed 000's weight
REMOVAL_STEP = 0.05  # the workpiece's inertia is updated in steps of 5 % of the blank
#: a fresh blank is clamped this long before a reversal's centre (the table near its
#: stroke end; the reversal right after it identifies the new J_L)
CLAMP_BEFORE_REVERSAL = 0.3
#: ... at the last such reversal before the blank is used up: the clamp is planned this
#: many seconds of removal ahead (two strokes). Waiting for a reversal with the blank
#: used up held J_L while the identifier extrapolated its fall (measured: J_L 10 % low
#: after 8 s, the DFO's amplitudes 6-8 % low)
CLAMP_LOOKAHEAD = 8.0


@dataclass
class WorkpieceState:
    """What the workpiece carries from block to block (checkpointed)."""

    removed: float = 0.0  # fraction of the current blank removed
    applied: float = 0.0  # the removal the plant has (steps, mid-stroke)
    clamp_pending: bool = False  # the blank is nearly used up; a fresh one is due
    pending_since: float = 0.0  # when the clamp became due [s]


class Workpiece:
    """The blank on a table that reverses every ``half_period`` seconds.

    Parameters
    ----------
    half_period
        Time between the table's reversals [s] (the trajectory's half period).
    spindle_factor
        The scenario's spindle factor at a time (a clamp avoids a reversal whose segment
        a spindle step spoils).
    """

    def __init__(self, half_period: float, spindle_factor: Callable[[float], float]) -> None:
        self.half_period = float(half_period)
        self._factor = spindle_factor
        self.state = WorkpieceState()

    def advance(self, t0: float, n: int, sample_time: float, rate: float) -> bool:
        """The block of ``n`` samples starting at ``t0`` removes ``rate`` (fraction per
        second) of the blank; True when a fresh blank is clamped at its start."""
        s = self.state
        if s.clamp_pending and self._clamp_now(t0):
            s.removed = 0.0  # a fresh blank is clamped
            s.clamp_pending = False
            return True
        s.removed = min(s.removed + rate * n * sample_time, 1.0)
        ahead = min(rate * CLAMP_LOOKAHEAD, 0.2)  # at most a fifth left uncut
        if not s.clamp_pending and s.removed >= 1.0 - ahead:
            s.clamp_pending = True
            s.pending_since = t0
        return False

    def inertia(self, t: float) -> float:
        """The blank's inertia on the load for the block starting at ``t`` [kg m^2].

        In steps of REMOVAL_STEP: each change of the plant costs a matrix exponential
        (~1-7 ms here), too much to pay every 50 ms block. A step is applied mid-stroke
        (>= 1 s from a reversal), where no acceleration shows it: a J_L step inside a
        reversal is an artefact of the steps (the mass goes continuously) and biased the
        identified B_L/F_CL when the steps fell on the reversals (removal 2.5 %/s: a step
        every 2 s, every reversal).
        """
        s = self.state
        removed = math.floor(s.removed / REMOVAL_STEP) * REMOVAL_STEP
        hp = self.half_period
        if s.removed == 0.0 or abs(t - round(t / hp) * hp) >= 1.0:
            s.applied = removed
        return WORKPIECE_INERTIA * (1.0 - s.applied)

    def _clamp_now(self, t0: float) -> bool:
        """Clamp the pending fresh blank at this block (start ``t0``)? Just before a
        reversal without a spindle step near it; if the blocks are too long to hit that
        instant, once three half periods have passed."""
        hp = self.half_period
        rev = (math.floor(t0 / hp) + 1) * hp
        if rev - t0 > CLAMP_BEFORE_REVERSAL:
            return t0 - self.state.pending_since > 3 * hp
        # not at a reversal whose segment a spindle step spoils (every 60 s here): J_L
        # would stay unknown until the next one (the DFO then reads a wrong J_L's
        # acceleration as harmonics, measured: amplitudes 33 % low for 4 s)
        return self._factor(rev - 1.0) == self._factor(rev + 1.0)


class WorkpiecePart(LivePart):
    """The blank on the simulated stage (module docstring); see :class:`Workpiece`."""

    name = "workpiece"

    def __init__(self, half_period: float, spindle_factor: Callable[[float], float]) -> None:
        self.workpiece = Workpiece(half_period, spindle_factor)

    def requires(self, machine: MachineView) -> Verdict:
        return needs_simulator(machine, "a workpiece losing mass on the stage")

    def before(self, plan: Plan) -> None:
        rate = float(plan.knobs["removal_rate"]) / 100.0
        if self.workpiece.advance(plan.t0, plan.n, plan.sample_time, rate):
            plan.notice(Notice("restart", plan.t0, ("J_L",)))  # a fresh blank: J_L changes

    def added_inertia(self, t: float) -> float:
        return self.workpiece.inertia(t)

    def step(self, block: Block) -> Outputs:
        return {}, []

    def state(self) -> WorkpieceState:
        return self.workpiece.state

    def restore(self, state: object) -> None:
        if not isinstance(state, WorkpieceState):
            raise ParameterError("state.parts.workpiece", "a WorkpieceState", type(state).__name__)
        self.workpiece.state = state
