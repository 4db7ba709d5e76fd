r"""A rigid feed axis as its drive sees it: motor encoder and effort (a semi-closed loop).

The carriage follows a jerk-limited back-and-forth motion (moves between random points
of the travel at random plateau speeds, with dwells), and the drive's effort is the
inverse dynamic model of EMPS's kind plus what a real drive adds and a rigid model does
not say:

.. math::

    \tau = M\ddot q + F_v\dot q + F_c\,\mathrm{sign}(\dot q) + \tau_{off}
         + A\sin(2\pi q/P + \varphi) + f(q)\,\mathrm{sign}(\dot q) + n(t)

a ripple periodic in position (cogging, lead error: amplitude ``ripple``, period
``ripple_period``), a friction that varies along the travel by direction (``f`` a
quadratic profile, peak ``position_friction``), and a coloured noise ``n`` (first-order
autoregressive with time constant ``noise_tau`` and rms ``noise_rms``: the current loop's
and the load's unmodelled dynamics). At rest the effort is the offset and the noise
(stiction holds the carriage). The position is quantised to ``resolution``. Everything
random comes from the generator passed in.

It is the test bench of the live rigid identifier (its parameters are the truth its
intervals should cover); it has no controller: the motion is imposed, the effort is what
the motion takes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.signal

from common.arrays import F64
from machine.errors import ParameterError, require_nonnegative, require_positive


@dataclass(frozen=True)
class RigidAxisParams:
    """The axis and its drive (SI units: m, N, s)."""

    M: float = 95.0
    Fv: float = 200.0
    Fc: float = 20.0
    offset: float = -3.0
    ripple: float = 1.0
    ripple_period: float = 2.5e-3
    position_friction: float = 2.0
    noise_rms: float = 1.5
    noise_tau: float = 0.02
    resolution: float = 5e-8
    travel: float = 0.25
    v_max: float = 0.125
    a_max: float = 2.0
    jerk_time: float = 0.02
    sample_time: float = 1e-3

    def __post_init__(self) -> None:
        for n in ("M", "ripple_period", "resolution", "travel", "v_max", "a_max", "sample_time"):
            require_positive(n, getattr(self, n))
        for n in ("Fv", "Fc", "ripple", "position_friction", "noise_rms", "noise_tau", "jerk_time"):
            require_nonnegative(n, getattr(self, n))
        if not math.isfinite(self.offset):
            raise ParameterError("offset", "a finite value", self.offset)


def _velocity_profile(rng: np.random.Generator, p: RigidAxisParams, n: int) -> F64:
    """Moves between random points of the travel at random plateau speeds (trapezoids
    at ``a_max``), with random dwells; samples of the commanded velocity."""
    ts = p.sample_time
    v = np.zeros(n)
    k, pos = 0, 0.5 * p.travel
    while k < n:
        k += int(rng.uniform(0.05, 0.6) / ts)  # dwell
        if k >= n:
            break
        target = rng.uniform(0.02, 0.98) * p.travel
        dist = target - pos
        vp = rng.uniform(0.2, 1.0) * p.v_max
        t_acc = vp / p.a_max
        if abs(dist) < vp * t_acc:  # a triangle: the plateau speed is not reached
            vp = math.sqrt(abs(dist) * p.a_max)
            t_acc = vp / p.a_max
        t_flat = abs(dist) / vp - t_acc
        m = np.arange(int((2 * t_acc + t_flat) / ts) + 1) * ts
        prof = np.minimum.reduce([m / t_acc, np.ones_like(m), (2 * t_acc + t_flat - m) / t_acc])
        seg = np.sign(dist) * vp * np.clip(prof, 0.0, 1.0)
        end = min(n, k + len(seg))
        v[k:end] = seg[: end - k]
        pos += float(np.sum(seg)) * ts
        k = end
    return v


def simulate_rigid_axis(
    p: RigidAxisParams, seconds: float, rng: np.random.Generator
) -> dict[str, F64]:
    """A record of ``seconds``: ``t``, ``q_m`` (quantised), ``tau_m``, and the truth's
    ``qd``, ``qdd``, ``model`` (the rigid part) and ``rest`` (what it does not say)."""
    ts = p.sample_time
    n = int(round(require_positive("seconds", seconds) / ts))
    v = _velocity_profile(rng, p, n)
    if p.jerk_time > 0:  # jerk limit: a moving average over jerk_time (two passes)
        w = max(1, int(round(p.jerk_time / ts)))
        ker = np.ones(w) / w
        v = np.convolve(np.convolve(v, ker, mode="full")[:n], ker, mode="full")[:n]
    # trapezoidal integration (starts in the middle of the travel): the central second
    # difference of q is then exactly the central difference of v (the model's a)
    q = 0.5 * p.travel + np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]))]) * ts
    a = np.gradient(v, ts)
    sgn = np.sign(np.where(np.abs(v) > 1e-9, v, 0.0))
    model = p.M * a + p.Fv * v + p.Fc * sgn + p.offset
    phase = rng.uniform(0.0, 2 * math.pi)
    x = np.clip(2.0 * q / p.travel - 1.0, -1.0, 1.0)
    shape = rng.uniform(-1.0, 1.0, 2)
    prof = p.position_friction * (shape[0] * x + shape[1] * (1.5 * x * x - 0.5))
    rest = p.ripple * np.sin(2 * math.pi * q / p.ripple_period + phase) * (sgn != 0)
    rest = rest + prof * sgn + _ar1(rng, n, p.noise_rms, p.noise_tau, ts)
    qm = np.round(q / p.resolution) * p.resolution
    return {"t": np.arange(n) * ts, "q_m": qm, "tau_m": model + rest, "qd": v, "qdd": a,
            "model": model, "rest": rest}  # fmt: skip


def _ar1(rng: np.random.Generator, n: int, rms: float, tau: float, ts: float) -> F64:
    """A first-order autoregressive noise of rms ``rms`` and time constant ``tau``."""
    if rms == 0:
        return np.zeros(n)
    rho = math.exp(-ts / tau) if tau > 0 else 0.0
    e = rng.normal(0.0, rms * math.sqrt(1 - rho * rho), n)
    e[0] = rng.normal(0.0, rms)  # the stationary start
    # n(k) = rho n(k-1) + e(k)
    return np.asarray(scipy.signal.lfilter([1.0], [1.0, -rho], e), dtype=np.float64)
