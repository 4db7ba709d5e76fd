r"""The spindle's cutting power: its power less the idle power taught in air at each speed.

A CNC gives the spindle's speed and power (or current, or load); what a process monitor
and a wear estimate want is the power the *cut* takes. A spindle turning in the air
takes power too, and not a constant: friction in the bearings and seals (Coulomb, so
its power grows with the speed) and the viscous and windage losses (growing with its
square), falling as the bearings warm up. So the idle power is taught per speed, from
the spindle's own signals while it turns in the air, and kept up to date.

Teaching, per speed bin (``bin_rpm`` wide) and sample: while the speed is steady (it has
changed by less than ``steady_rpm_per_s`` for at least ``hold_s``: the power smoothing
and the acceleration power have settled), the bin's idle power tracks a low quantile
(``quantile``) of the power measured at that speed by the stochastic quantile
recursion

.. math:: \hat P_0 \leftarrow \hat P_0 + \eta\,(q - \mathbf 1[P < \hat P_0]),
          \qquad \eta = \text{gain}\cdot\max(\hat P_0, P_{floor}),

whose fixed point has a share ``q`` of the samples below it. A spindle spends part of
its time at every speed in the air (the approach, the plunge, the rapids between cuts),
so the low quantile is the air's power: no cut is needed to be marked as such; the cuts
(a share ``1 - q`` of the time may cut) only push it up by ``eta q`` per sample. The
recursion steps down ``(1-q)/q`` times faster than up: it follows the warm-up's falling
friction at once and a rise in minutes.

Between and beyond the bins taught, the idle power is the friction model fitted to the
taught bins by weighted least squares, :math:`P_0(\omega) = c_1\omega + c_2\omega^2`
(Coulomb and viscous; weights: the samples each bin has seen). The cutting power is
:math:`P - \hat P_0(n)`; with no bin taught yet it is NaN (not known), never a guess.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit
from numpy.typing import ArrayLike

from common.arrays import F64
from estimators.errors import ParameterError, require_in, require_positive

#: samples a bin must have learned from before its value is used
_MIN_SEEN_S = 0.2


@dataclass(frozen=True)
class IdlePowerParams:
    """The idle-power teacher.

    Parameters
    ----------
    sample_time : float
        Of the speed and power signals [s].
    bin_rpm : float
        Width of a speed bin [rpm].
    max_rpm : float
        The highest speed taught [rpm].
    min_rpm : float
        Below this the spindle is taken as stopped (nothing taught, idle 0).
    quantile : float
        The share of a bin's samples below its idle power, in (0, 0.5).
    gain : float
        Step of the quantile recursion per sample, as a share of the estimate.
    floor_w : float
        The smallest step scale [W].
    steady_rpm_per_s : float
        The speed changes slower than this while it is steady [rpm/s].
    hold_s : float
        Steady this long before a sample teaches [s].
    """

    sample_time: float
    bin_rpm: float = 250.0
    max_rpm: float = 24_000.0
    min_rpm: float = 300.0
    quantile: float = 0.005
    gain: float = 4e-5
    floor_w: float = 20.0
    steady_rpm_per_s: float = 500.0
    hold_s: float = 0.1

    def __post_init__(self) -> None:
        require_in("sample_time", self.sample_time, 1e-4, 0.1)
        for n in ("bin_rpm", "max_rpm", "min_rpm", "floor_w", "steady_rpm_per_s", "hold_s"):
            require_positive(n, getattr(self, n))
        require_in("quantile", self.quantile, 0.0, 0.5, lo_open=True, hi_open=True)
        require_in("gain", self.gain, 0.0, 0.1, lo_open=True)
        if self.max_rpm <= self.min_rpm + self.bin_rpm:
            low = self.min_rpm + self.bin_rpm
            raise ParameterError("max_rpm", f"> min_rpm + bin_rpm ({low:g})", self.max_rpm)

    @property
    def n_bins(self) -> int:
        return int(math.ceil(self.max_rpm / self.bin_rpm)) + 1


@dataclass
class IdlePowerState:
    """Each bin's idle power [W] and the samples it learned from; the last speed [rpm] and
    how long [s] the speed has been steady."""

    idle: F64
    seen: F64
    last_rpm: float = math.nan
    steady_s: float = 0.0


@dataclass
class IdlePowerRecord:
    """Per sample: the idle power at the measured speed [W] (NaN: not taught), the cutting
    power [W] (power less idle; NaN where the idle is not known), whether the sample
    taught; and the fitted friction model ``c1`` [N m], ``c2`` [N m s] (NaN: fewer than
    two bins taught)."""

    idle: F64
    cutting: F64
    taught: np.ndarray
    c1: float
    c2: float


class TeachDesign(NamedTuple):
    """The quantile recursion's design as :func:`_teach` takes it (scalars; made per
    block from :class:`IdlePowerParams`)."""

    ts: float  # sample time [s]
    bin_rpm: float  # width of a speed bin [rpm]
    min_rpm: float  # below it the spindle is stopped [rpm]
    q: float  # the share of a bin's samples below its idle power
    gain: float  # step of the recursion per sample, a share of the estimate
    floor_w: float  # the smallest step scale [W]
    steady: float  # steady: the speed changes slower than this [rpm/s]
    hold: float  # steady this long before a sample teaches [s]


@njit(cache=True)
def _teach(
    d: TeachDesign, rpm: F64, power: F64, idle: F64, seen: F64, st: F64, taught: F64
) -> None:  # pragma: no cover
    """The quantile recursion over a block (``idle``, ``seen``, ``st = [last_rpm,
    steady_s]`` in place)."""
    ts, bin_rpm, min_rpm, q, gain = d.ts, d.bin_rpm, d.min_rpm, d.q, d.gain
    floor_w, steady, hold = d.floor_w, d.steady, d.hold
    nb = idle.shape[0]
    for k in range(rpm.shape[0]):
        n = rpm[k]
        p = power[k]
        if math.isnan(st[0]) or abs(n - st[0]) > steady * ts:
            st[1] = 0.0
        else:
            st[1] += ts
        st[0] = n
        taught[k] = 0.0
        if n < min_rpm or st[1] < hold or not math.isfinite(p):
            continue
        b = int(n / bin_rpm + 0.5)
        if b >= nb:
            continue
        if seen[b] == 0.0:
            idle[b] = p
        else:
            eta = gain * max(idle[b], floor_w)
            idle[b] += eta * (q - (1.0 if p < idle[b] else 0.0))
        seen[b] += 1.0
        taught[k] = 1.0


class IdlePower:
    """Teach the idle power per speed and give the cutting power (module docstring).

    Examples
    --------
    >>> ip = IdlePower(IdlePowerParams(sample_time=0.002))
    >>> s = ip.initial_state()
    >>> s, rec = ip.step(s, np.full(500, 8000.0), np.full(500, 700.0))
    >>> round(float(rec.idle[-1]))
    700
    """

    def __init__(self, params: IdlePowerParams) -> None:
        self.params = params
        self._min_seen = _MIN_SEEN_S / params.sample_time

    def initial_state(self) -> IdlePowerState:
        nb = self.params.n_bins
        return IdlePowerState(idle=np.full(nb, np.nan), seen=np.zeros(nb))

    def step(
        self, state: IdlePowerState, speed_rpm: ArrayLike, power_w: ArrayLike
    ) -> tuple[IdlePowerState, IdlePowerRecord]:
        """Teach from one block of the spindle's speed [rpm] and power [W]; the block's idle
        and cutting power."""
        rpm = np.abs(np.ascontiguousarray(speed_rpm, dtype=np.float64))
        p = np.ascontiguousarray(power_w, dtype=np.float64)
        if rpm.ndim != 1 or p.shape != rpm.shape:
            raise ParameterError(
                "power_w", f"a 1-D block shaped like speed_rpm {rpm.shape}", p.shape
            )
        pr = self.params
        idle, seen = state.idle.copy(), state.seen.copy()
        st = np.array([state.last_rpm, state.steady_s])
        taught = np.zeros(len(rpm))
        design = TeachDesign(pr.sample_time, pr.bin_rpm, pr.min_rpm, pr.quantile, pr.gain,
                             pr.floor_w, pr.steady_rpm_per_s, pr.hold_s)  # fmt: skip
        _teach(design, rpm, p, idle, seen, st, taught)
        new = IdlePowerState(idle, seen, float(st[0]), float(st[1]))
        c1, c2 = self.model(new)
        at = self.idle_at(new, rpm, (c1, c2))
        return new, IdlePowerRecord(at, p - at, taught.astype(bool), c1, c2)

    def model(self, state: IdlePowerState) -> tuple[float, float]:
        """``(c1, c2)`` of :math:`P_0 = c_1\\omega + c_2\\omega^2` fitted to the taught bins
        (NaN, NaN with fewer than two)."""
        ok = np.flatnonzero(state.seen >= self._min_seen)
        if len(ok) < 2:
            return math.nan, math.nan
        w = ok * self.params.bin_rpm * math.pi / 30.0
        sw = np.sqrt(state.seen[ok])
        a = np.column_stack([w, w * w]) * sw[:, None]
        c, *_ = np.linalg.lstsq(a, state.idle[ok] * sw, rcond=None)
        return float(c[0]), float(c[1])

    def idle_at(
        self, state: IdlePowerState, speed_rpm: ArrayLike, model: tuple[float, float] | None = None
    ) -> F64:
        """The idle power [W] at ``speed_rpm``: the speed's own bin where it is taught,
        else the fitted model; 0 below ``min_rpm``; NaN where nothing is known."""
        rpm = np.abs(np.asarray(speed_rpm, dtype=np.float64))
        c1, c2 = model if model is not None else self.model(state)
        b = np.clip(np.round(rpm / self.params.bin_rpm).astype(np.int64), 0, len(state.idle) - 1)
        own = np.where(state.seen[b] >= self._min_seen, state.idle[b], np.nan)
        w = rpm * math.pi / 30.0
        out = np.where(np.isfinite(own), own, c1 * w + c2 * w * w)
        return np.asarray(np.where(rpm < self.params.min_rpm, 0.0, out), dtype=np.float64)


__all__ = ["IdlePower", "IdlePowerParams", "IdlePowerRecord", "IdlePowerState"]
