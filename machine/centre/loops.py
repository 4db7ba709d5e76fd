r"""The drives' control loops as linear discrete systems: stability and bandwidths.

The kernel's loops (:mod:`machine.centre.kernel`) without their non-linear parts
(friction, quantisation, limits), written as one discrete state-space system per loop at
the simulation rate, in the kernel's own order of operations:

- states of a feed axis: the mechanics ``[x_m, v_m, x_l, v_l]`` (``[x, v]`` on a rigid
  axis), the current loop's force, the filtered speed, the speed integral, the previous
  encoder position;
- states of the spindle: speed, the current loop's torque, the filtered speed, the
  speed integral.

The matrices are found by applying one sample of the loop to unit vectors (the loop is
linear without the limits), so they follow the kernel's arithmetic without a second
derivation. :func:`bandwidth_hz` is where the closed loop's magnitude response first
falls below 1/sqrt(2) (-3 dB); :func:`stable` asks for every eigenvalue inside the unit
circle.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from common.arrays import F64
from machine.centre.params import CentreParams, FeedAxisParams, SpindleParams
from machine.errors import ParameterError

_N_AXIS = 8
_N_SPINDLE = 4


def _axis_sample(ax: FeedAxisParams, workpiece: float, ts: float, loop: str) -> Callable[
    [F64, float], tuple[F64, float]
]:  # fmt: skip
    """One sample of an axis' linear loop: ``(state, input) -> (next state, output)``;
    input the speed setpoint (``loop='speed'``), the position command (``'position'``),
    or its velocity or acceleration feed-forward alone (``'vff'``, ``'aff'``); output the
    motor speed or the load position."""
    from machine.centre.sim import _axis_matrices, _pack_axis

    phi, gam = _axis_matrices(ax, workpiece, ts)
    p = _pack_axis(ax, workpiece, ts)
    from machine.centre import kernel as kn

    def sample(s: F64, u: float) -> tuple[F64, float]:
        x = s[:4]
        fa, vf, integ, qprev = s[4], s[5], s[6], s[7]
        xm, xl = x[0], x[2]
        vf = vf + p[kn.AP_BF] * ((xm - qprev) / ts - vf)
        fb = xl if ax.kind == "two_inertia" else xm
        r = u if loop == "position" else 0.0
        v_set = u if loop == "speed" else p[kn.AP_KV] * (r - fb) + (u if loop == "vff" else 0.0)
        e = v_set - vf
        f_set = p[kn.AP_KP] * e + integ + (p[kn.AP_MFF] * u if loop == "aff" else 0.0)
        integ = integ + p[kn.AP_KI] * ts * e
        x_next = phi @ x + gam @ np.array([fa, 0.0])
        fa_next = fa + p[kn.AP_BI] * (f_set - fa)
        out = x[1] if loop == "speed" else (x[2] if ax.kind == "two_inertia" else x[0])
        return np.concatenate([x_next, [fa_next, vf, integ, xm]]), float(out)

    return sample


def _spindle_sample(sp: SpindleParams, ts: float) -> Callable[[F64, float], tuple[F64, float]]:
    from machine.centre import kernel as kn
    from machine.centre.sim import _pack_spindle

    p = _pack_spindle(CentreParams(spindle=sp, sample_time=ts))

    def sample(s: F64, u: float) -> tuple[F64, float]:
        w, ta, wf, integ = s
        wf = wf + p[kn.SP_BF] * (w - wf)
        e = u - wf
        t_set = p[kn.SP_KP] * e + integ
        integ = integ + p[kn.SP_KI] * ts * e
        w_next = p[kn.SP_E1] * w + p[kn.SP_E2] * ta
        ta_next = ta + p[kn.SP_BI] * (t_set - ta)
        return np.array([w_next, ta_next, wf, integ]), float(w)

    return sample


def _matrices(
    sample: Callable[[F64, float], tuple[F64, float]], n: int
) -> tuple[F64, F64, F64, float]:
    """``A, B, C, D`` of ``x+ = A x + B u, y = C x + D u`` from a linear one-sample map."""
    a = np.zeros((n, n))
    c = np.zeros(n)
    for i in range(n):
        e = np.zeros(n)
        e[i] = 1.0
        a[:, i], c[i] = sample(e, 0.0)
    b, d = sample(np.zeros(n), 1.0)
    return a, b, c, d


def closed_loop(
    which: str, params: CentreParams | None = None, *, loop: str = "speed",
    workpiece: float = 0.0,
) -> tuple[F64, F64, F64, float]:  # fmt: skip
    """The linear closed loop of axis ``which`` (``X``, ``Y``, ``Z``) or the spindle
    (``S``), as ``(A, B, C, D)``; ``loop`` is ``speed`` or ``position`` (axes)."""
    pr = params if params is not None else CentreParams()
    ts = pr.sample_time
    if which == "S":
        return _matrices(_spindle_sample(pr.spindle, ts), _N_SPINDLE)
    names = {a.name: a for a in pr.axes}
    if which not in names:
        raise ParameterError("which", "one of ['X', 'Y', 'Z', 'S']", which)
    if loop not in ("speed", "position", "vff", "aff"):
        raise ParameterError("loop", "one of 'speed', 'position', 'vff', 'aff'", loop)
    a, b, c, d = _matrices(_axis_sample(names[which], workpiece, ts, loop), _N_AXIS)
    if names[which].kind == "rigid":
        # a rigid axis is simulated as two equal copies of one mass; nothing reads the
        # second (states 2, 3): it is left out of the loop
        keep = [0, 1, 4, 5, 6, 7]
        a, b, c = a[np.ix_(keep, keep)], b[keep], c[keep]
    return a, b, c, d


def response(sys: tuple[F64, F64, F64, float], f_hz: F64, ts: float) -> NDArray[np.complex128]:
    """Frequency response ``y/u`` of a discrete system at ``f_hz``."""
    a, b, c, d = sys
    out = np.empty(len(f_hz), dtype=np.complex128)
    eye = np.eye(a.shape[0])
    for i, f in enumerate(np.asarray(f_hz, dtype=np.float64)):
        z = complex(math.cos(2 * math.pi * f * ts), math.sin(2 * math.pi * f * ts))
        out[i] = c @ np.linalg.solve(z * eye - a, b) + d
    return out


def tracking_response(
    which: str, f_hz: float, params: CentreParams | None = None, *, workpiece: float = 0.0
) -> complex:
    """Load position over a sinusoidal command at ``f_hz`` through axis ``which``'s loop
    with the kernel's velocity and acceleration feed-forward (the command's own derivatives,
    ``j w r`` and ``-w^2 r``), e.g. seed003 (7)'s circle at the spindle frequency."""
    pr = params if params is not None else CentreParams()
    ts = pr.sample_time
    w = 2.0 * math.pi * f_hz
    f = np.array([f_hz])
    g = response(closed_loop(which, pr, loop="position", workpiece=workpiece), f, ts)[0]
    g += 1j * w * response(closed_loop(which, pr, loop="vff", workpiece=workpiece), f, ts)[0]
    g -= w * w * response(closed_loop(which, pr, loop="aff", workpiece=workpiece), f, ts)[0]
    return complex(g)


def stable(sys: tuple[F64, F64, F64, float]) -> float:
    """The spectral radius of the closed loop (< 1: stable)."""
    return float(np.max(np.abs(np.linalg.eigvals(sys[0]))))


def bandwidth_hz(sys: tuple[F64, F64, F64, float], ts: float, f_max: float = 2000.0) -> float:
    """First frequency where the closed loop's gain falls below -3 dB (relative to its
    gain at 0.1 Hz) [Hz]; ``nan`` if not below ``f_max``."""
    f = np.geomspace(0.1, f_max, 4000)
    g = np.abs(response(sys, f, ts))
    below = np.flatnonzero(g < g[0] / math.sqrt(2.0))
    if below.size == 0:
        return math.nan
    i = int(below[0])
    # interpolate in log frequency between the last point above and the first below
    g0, g1 = g[i - 1], g[i]
    lvl = g[0] / math.sqrt(2.0)
    w = (g0 - lvl) / (g0 - g1)
    return float(math.exp((1 - w) * math.log(f[i - 1]) + w * math.log(f[i])))


__all__ = ["bandwidth_hz", "closed_loop", "response", "stable", "tracking_response"]
