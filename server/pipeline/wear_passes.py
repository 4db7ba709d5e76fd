"""Tool wear in the live pipeline: seed 004's wear model pass by pass, its monitor fed by
the adaptive observer, the tool changed at the flank-wear limit.

The wear raises the cutting force on the stage (gain = pass force / sharp force), as a
ramp over each pass whose mean is the pass's force, continuing the previous pass's slope:
the wear grows the force smoothly. The life monitor is fed the force the adaptive
observer sees, back in the wear model's newtons:
``F_sharp * mean(f_adaptive) / mean(force without wear)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from common.arrays import F64
from harness.wear_clock import AcceleratedToolWear

PASS_S = 1.0  # one tool-wear pass per second of simulated time
#: the wear clock of the first tool starts once the observers have settled (their first
#: second reads ~3 % low, which biased the monitor's sharp-tool force, seed004 (25), and with
#: it every later VB by ~+0.03 mm); later tools start at once (observers settled)
WEAR_WARMUP_S = 5.0
VB_LIMIT = 0.3  # flank wear at which the tool is changed [mm] (seed 004's limit)


@dataclass
class PassState:
    """The tool and its pass under way (checkpointed; the wear model's own state is in
    :class:`~harness.wear_clock.AcceleratedToolWear`)."""

    #: the force gain ramp over the pass: (gain at the pass start, slope per second, start)
    gain_ramp: tuple[float, float, float] = (1.0, 0.0, 0.0)
    first_pass: bool = True
    est: float = 0.0  # sum of the observer's force over the pass
    nom: float = 0.0  # sum of the nominal (sharp-tool) force over the pass
    seconds: float = 0.0  # machining time in the pass
    cut: tuple[float, F64] | None = None  # (mean force, wear at end) of the pass under way
    prev_nominal: float = math.nan  # nominal force of the previous block (none yet)
    steady: bool = True  # no change of cutting condition within the pass
    vb_true: float = 0.0
    vb_est: float = math.nan
    life_left: float = math.nan
    tools_changed: int = 0
    #: when the tool in the spindle was mounted [s of the source] (its life record's start)
    tool_start_t: float = 0.0


class ToolWearPasses:
    """The wearing tool of a scenario (see the module docstring).

    Parameters
    ----------
    wear_rate
        Minutes of wear per second of machining for the first tool.
    """

    def __init__(self, wear_rate: float) -> None:
        self.state = PassState()
        self.wear = self._tool(wear_rate)
        # force of the sharp tool (seed004 (8) at zero wear): the stage's force is scaled
        # by the wear model's force over this one
        self.f_sharp = self.wear.model.force(np.zeros(3), self.wear.feed)

    @staticmethod
    def _tool(wear_rate: float) -> AcceleratedToolWear:
        # life_sd=False: the stream shows VB and the remaining life, not its spread,
        # which is ~4/5 of the monitor's time per pass (docs/benchmarks.md)
        return AcceleratedToolWear(wear_minutes_per_second=wear_rate, life_sd=False)

    def new_tool(self, wear_rate: float) -> None:
        """A sharp tool (counted in ``tools_changed``)."""
        changed = self.state.tools_changed + 1
        self.wear = self._tool(wear_rate)
        self.f_sharp = self.wear.model.force(np.zeros(3), self.wear.feed)
        self.state = PassState(tools_changed=changed)

    def gain(self, t: float) -> float:
        """The wear's force gain at ``t``."""
        g0, slope, tp = self.state.gain_ramp
        return g0 + slope * max(t - tp, 0.0)

    def begin(self, t0: float, wear_rate: float) -> None:
        """Start a pass: advance the wear model over it first, so the stage cuts with the
        pass's own wear force (no one-pass lag between the force and the wear clock)."""
        s = self.state
        if s.cut is not None or t0 < WEAR_WARMUP_S - 1e-9:
            return
        w = self.wear
        w.rate = wear_rate
        _, f_true, x = w.cut_pass(PASS_S)
        s.cut = (f_true, x)
        # A ramp over the pass whose mean is the pass's force, continuing the previous
        # pass's slope. (It was held in 1 % steps at the pass starts, which fall on the
        # reversals every 4 s: a DC step inside a reversal reads as Coulomb friction,
        # docs/live-identification.md.) A force change costs no matrix exponential
        # (StageSim re-discretises only on a plant change).
        g = f_true / self.f_sharp
        g_prev = s.gain_ramp[0] + 0.5 * s.gain_ramp[1] * PASS_S
        if s.first_pass:
            g_prev = g  # the first pass of a tool
            s.first_pass = False
        slope = (g - g_prev) / PASS_S
        s.gain_ramp = (g - 0.5 * slope * PASS_S, slope, t0)

    def interrupt(self) -> None:
        """The measurements broke off (a discontinuity): the pass under way is not given
        to the monitor."""
        if self.state.cut is not None:
            self.state.steady = False

    def accumulate(self, n: int, f_est: F64, nominal: float, sample_time: float) -> bool:
        """Add a block of the observer's force ``f_est`` (the sharp tool's force would be
        ``nominal``) to the pass; close the pass every PASS_S. True when the pass reached
        the flank-wear limit (the tool is to be changed)."""
        s = self.state
        if s.cut is None:  # the wear clock has not started yet
            return False
        # the mean of the observer's force over a pass is the offset's (the harmonics
        # average out); the nominal mean is what it would be with a sharp tool
        prev, s.prev_nominal = s.prev_nominal, nominal
        if not math.isnan(prev) and nominal != prev:  # changed in the pass or at its start
            s.steady = False
        s.est += float(np.sum(f_est))
        s.nom += n * nominal
        s.seconds += n * sample_time
        if s.seconds < PASS_S - 1e-9:
            return False
        _, x = s.cut
        # a pass in which, or at whose start, the cutting condition changed (spindle step,
        # feed) is not given to the monitor: the observers' transient after the step
        # biases its mean (measured -0.04 mm on VB for the pass after a spindle step)
        if s.nom > 0.0 and s.steady:
            rec = self.wear.observe_pass(self.f_sharp * s.est / s.nom)
            s.vb_est = float(rec.vb[-1])
            s.life_left = float(rec.remaining_life[-1])
        s.vb_true = float(x[0] + x[1])  # flank wear w_f1 + w_f2
        s.est = s.nom = s.seconds = 0.0
        s.steady = True
        s.cut = None
        return s.vb_true >= VB_LIMIT  # the tool is changed at the flank-wear limit
