"""Live wear, honestly (issue 35 item 7): the hybrid's map fitted from one machine's own
labelled tool lives, "uncalibrated" with the prior's interval until enough exist.

A labelled life is a tool's segments (the signals the machine gives, its feed rate) with
its VB when it went in and the VB measured when it came out (a tool change, entered in
the tool-life record). Between the two the VB is taken as linear in the segment index -
the same interpolation the published turning table uses between its measurements.

Until ``min_lives`` lives of *this* machine are in, the estimate is the no-signal prior
(the start VB plus the median rate of the lives seen so far, or of a caller's default
when there are none) with an interval from the spread of those rates; status
``uncalibrated``. From then on the configuration is chosen by leave-one-life-out over the
lives (the nested evaluation's inner loop), the map is fitted on all of them and the
interval is CV+ over the lives; status ``calibrated``. A life from another machine, or
a machine of another kind (a lathe's map carried to a milling spindle), is refused.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from common.arrays import F64
from estimators.errors import ParameterError
from estimators.wear.hybrid import HybridConfig, HybridModel, ToolData, candidates, fit

KINDS = ("lathe", "mill")
#: labelled lives needed before the map is used (leave-one-life-out needs 2 to fit on)
MIN_LIVES = 3


@dataclass(frozen=True)
class LabelledLife:
    """One tool's life on one machine, its VB measured at the change."""

    machine: str
    kind: str
    tool: int
    x: F64
    feed: F64
    vb_start: float
    vb_end: float

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ParameterError("kind", f"one of {KINDS}", self.kind)
        if len(self.x) < 2 or len(self.x) != len(self.feed):
            raise ParameterError(
                "x", f"2 or more segments, as many as feed ({len(self.feed)})", len(self.x)
            )
        if not (self.vb_end >= self.vb_start >= 0.0):
            raise ParameterError("vb_end", f">= vb_start ({self.vb_start}) >= 0", self.vb_end)

    def tool_data(self) -> ToolData:
        vb = np.linspace(self.vb_start, self.vb_end, len(self.feed))
        x = np.asarray(self.x, dtype=np.float64).reshape(len(self.feed), -1)
        return ToolData(self.tool, x, np.asarray(self.feed, dtype=np.float64), vb, self.vb_start)


@dataclass
class WearEstimate:
    status: str  # "uncalibrated" | "calibrated"
    vb: F64
    lo: F64
    hi: F64
    config: str = ""


@dataclass
class MachineWear:
    """The wear estimate of one machine from its own labelled lives."""

    machine: str
    kind: str
    default_rate: float = 1.0  # um / segment, used while no life is in
    default_rate_sd: float = 1.0
    min_lives: int = MIN_LIVES
    configs: Sequence[HybridConfig] = field(default_factory=lambda: candidates(revision=1))
    alpha: float = 0.05
    lives: list[LabelledLife] = field(default_factory=list)
    _model: HybridModel | None = None
    _loo: list[tuple[HybridModel, F64]] = field(default_factory=list)

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ParameterError("kind", f"one of {KINDS}", self.kind)

    @property
    def status(self) -> str:
        return "calibrated" if self._model is not None else "uncalibrated"

    def add_life(self, life: LabelledLife) -> None:
        """Add a life of this machine; refit when there are enough."""
        if life.machine != self.machine:
            raise ParameterError("machine", repr(self.machine), repr(life.machine))
        if life.kind != self.kind:
            raise ParameterError(
                "kind",
                f"{self.kind!r} (a map is not carried between machine kinds)",
                repr(life.kind),
            )
        if self.lives and np.shape(life.x)[1:] != np.shape(self.lives[0].x)[1:]:
            raise ParameterError(
                "x", f"{np.shape(self.lives[0].x)[1:]} signals per segment", np.shape(life.x)[1:]
            )
        self.lives.append(life)
        if len(self.lives) >= self.min_lives:
            self._calibrate()

    def _calibrate(self) -> None:
        tools = [lf.tool_data() for lf in self.lives]
        best, best_score = None, math.inf
        for c in self.configs:
            errs = []
            for i, t in enumerate(tools):
                m = fit([u for j, u in enumerate(tools) if j != i], c)
                est, _, _ = m.run(t)
                assert t.vb is not None
                errs.append(float(np.mean(np.abs(est - t.vb))))
            if float(np.mean(errs)) < best_score:
                best, best_score = c, float(np.mean(errs))
        assert best is not None
        self._model = fit(tools, best)
        self._loo = []
        for i, t in enumerate(tools):
            m = fit([u for j, u in enumerate(tools) if j != i], best)
            est, sd, _ = m.run(t)
            assert t.vb is not None
            self._loo.append((m, np.abs(t.vb - est) / sd))

    def _prior(self, n: int, start: float) -> WearEstimate:
        if self.lives:
            rates = [(lf.vb_end - lf.vb_start) / (len(lf.feed) - 1) for lf in self.lives]
            r = float(np.median(rates))
            rsd = max(float(np.std(rates)), 0.25 * r, 1e-3)
        else:
            r, rsd = self.default_rate, self.default_rate_sd
        k = np.arange(n, dtype=np.float64)
        z = 1.959963984540054
        vb = start + r * k
        return WearEstimate(
            "uncalibrated",
            vb,
            np.maximum(start + (r - z * rsd) * k, start),
            vb + z * rsd * k,
            "prior",
        )

    def estimate(self, x: F64, feed: F64, *, start_vb: float | None = None) -> WearEstimate:
        """VB of a tool on this machine, per segment so far, with a 95 % interval."""
        xx = np.asarray(x, dtype=np.float64).reshape(len(feed), -1)
        if self._model is None:
            return self._prior(len(feed), 0.0 if start_vb is None else start_vb)
        tool = ToolData(-1, xx, np.asarray(feed, dtype=np.float64), None, start_vb)
        est, _, _ = self._model.run(tool)
        lows, highs, ws = [], [], []
        for m, a in self._loo:
            mu, sg, _ = m.run(tool)
            lows.append(mu[:, None] - a[None, :] * sg[:, None])
            highs.append(mu[:, None] + a[None, :] * sg[:, None])
            ws.append(np.full(len(a), 1.0 / len(a)))
        w = np.concatenate(ws)
        lo = _wq(np.hstack(lows), w, self.alpha / 2)
        hi = _wq(np.hstack(highs), w, 1 - self.alpha / 2)
        return WearEstimate("calibrated", est, lo, hi, self._model.config.label)


def _wq(values: F64, weights: F64, q: float) -> F64:
    o = np.argsort(values, axis=1)
    v = np.take_along_axis(values, o, axis=1)
    cw = np.cumsum(weights[o], axis=1)
    cw /= cw[:, -1:]
    j = np.argmax(cw >= q - 1e-12, axis=1)
    return v[np.arange(len(v)), j]


__all__ = ["KINDS", "MIN_LIVES", "LabelledLife", "MachineWear", "WearEstimate"]
