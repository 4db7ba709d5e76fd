r"""Stability lobes of a milling cut: the boundary depth at each spindle speed.

Two methods over the same inputs (a :class:`~common.modes.ModalModel`, a
:class:`~common.cut_geometry.CutGeometry` with flutes, radial immersion, up/down
milling and the cutting coefficients):

- the zero-order approximation of Altintas and Budak (:mod:`estimators.chatter.zoa`):
  the directional matrix averaged, a closed-form boundary; blind to the period-doubling
  (flip) lobes of interrupted cuts;
- the semi-discretization of Insperger and Stepan (:mod:`estimators.chatter.sd`): the
  Floquet multipliers of the periodic delay equation; every kind of loss of stability.

The SD boundary at a speed is the smallest depth whose critical multiplier leaves the
unit circle: a scan of depths growing by a fixed ratio, then bisection on the first
bracket (an unstable island thinner than one scan step can be stepped over; the scan
ratio is a parameter). Converged SD (the reference of docs/chatter.md): ``m`` doubled
from 100 until the boundary moves less than 0.5 % from ``m/2``
(:func:`converged_boundary`); the chart uses the rule of :func:`intervals_for`, which
meets that criterion at the benchmark speeds (checked by the reproduction).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from common.arrays import F64
from common.cut_geometry import CutGeometry
from common.modes import ModalModel
from estimators.chatter.sd import DEFAULT_INTERVALS, Multiplier, SemiDiscretization
from estimators.chatter.zoa import zoa_chart
from estimators.errors import ParameterError, require_positive

#: intervals per period of the highest mode that :func:`intervals_for` asks for
INTERVALS_PER_MODE_PERIOD = 80


def intervals_for(modal: ModalModel, cut: CutGeometry, rpm: float, minimum: int = 100) -> int:
    """SD intervals for a speed: at least ``minimum``, and at least
    :data:`INTERVALS_PER_MODE_PERIOD` per period of the highest mode (slow speeds fit
    many vibration periods into one tooth period and need more)."""
    tau = cut.tooth_period(rpm)
    return max(int(minimum), math.ceil(INTERVALS_PER_MODE_PERIOD * tau * modal.highest_hz))


@dataclass(frozen=True)
class Boundary:
    """The SD stability boundary at one speed."""

    rpm: float
    depth: float  #: [m]; inf when stable up to the scan's top
    kind: str  #: "hopf", "flip" or "fold" (the critical multiplier's); "" when none
    intervals: int


def first_crossing(
    unstable: Callable[[float], bool],
    lo: float,
    hi: float,
    *,
    ratio: float = 1.15,
    rtol: float = 1e-4,
) -> float:
    """The smallest ``x`` in ``[lo, hi]`` where ``unstable(x)``, to a relative ``rtol``:
    a geometric scan by ``ratio`` then bisection of the first bracket; ``inf`` when the
    whole scan is stable. ``unstable(lo)`` true returns ``lo``."""
    if not (0.0 < lo < hi) or ratio <= 1.0:
        raise ParameterError("lo/hi/ratio", "0 < lo < hi and ratio > 1", (lo, hi, ratio))
    prev = lo
    if unstable(lo):
        return lo
    x = lo
    while x < hi:
        x = min(x * ratio, hi)
        if unstable(x):
            a, b = prev, x
            while b - a > rtol * b:
                mid = 0.5 * (a + b)
                if unstable(mid):
                    b = mid
                else:
                    a = mid
            return b
        prev = x
    return math.inf


def sd_boundary(
    sd: SemiDiscretization,
    rpm: float,
    *,
    depth_range: tuple[float, float] = (2e-5, 0.05),
    ratio: float = 1.15,
    rtol: float = 1e-4,
) -> Boundary:
    """The smallest unstable depth at ``rpm`` by ``sd`` (scan, then bisection)."""
    r = require_positive("rpm", rpm)
    d = first_crossing(
        lambda a: sd.spectral_radius(r, a) >= 1.0, *depth_range, ratio=ratio, rtol=rtol
    )
    kind = sd.multiplier(r, d).kind if math.isfinite(d) else ""
    return Boundary(r, d, kind, sd.intervals)


def converged_boundary(
    modal: ModalModel,
    cut: CutGeometry,
    rpm: float,
    *,
    start: int = DEFAULT_INTERVALS,
    tol: float = 0.005,
    max_intervals: int = 3200,
    **kw: float | tuple[float, float],
) -> tuple[Boundary, float]:
    """The SD boundary with ``m`` doubled from ``start`` until it moves less than ``tol``
    (relative) from ``m/2``; returns it and that last relative change."""
    m = int(start)
    prev = sd_boundary(SemiDiscretization(modal, cut, m // 2), rpm, **kw)  # type: ignore[arg-type]
    while True:
        cur = sd_boundary(SemiDiscretization(modal, cut, m), rpm, **kw)  # type: ignore[arg-type]
        change = abs(cur.depth / prev.depth - 1.0) if math.isfinite(cur.depth) else 0.0
        if change < tol or 2 * m > max_intervals:
            return cur, change
        prev, m = cur, 2 * m


@dataclass(frozen=True)
class LobeChart:
    """Both methods' boundaries over a speed range."""

    rpm: F64
    sd_depth: F64  #: [m]
    sd_kind: tuple[str, ...]
    zoa_depth: F64  #: [m]
    zoa_freq_hz: F64

    def gap(self) -> F64:
        """ZOA relative to SD, ``zoa/sd - 1`` at each speed."""
        return np.asarray(self.zoa_depth / self.sd_depth - 1.0)


def lobe_chart(
    modal: ModalModel,
    cut: CutGeometry,
    rpms: F64,
    *,
    progress: Callable[[int, int], None] | None = None,
    **kw: float | tuple[float, float],
) -> LobeChart:
    """The SD (intervals by :func:`intervals_for`) and ZOA boundaries at each speed."""
    r = np.asarray(rpms, dtype=float)
    if r.ndim != 1 or r.size == 0 or not np.all(np.isfinite(r)) or np.any(r <= 0):
        raise ParameterError("rpms", "a 1-D array of speeds > 0 [rpm]", rpms)
    cache: dict[int, SemiDiscretization] = {}
    bounds = []
    for i, x in enumerate(r):
        m = intervals_for(modal, cut, float(x))
        sd = cache.get(m) or cache.setdefault(m, SemiDiscretization(modal, cut, m))
        bounds.append(sd_boundary(sd, float(x), **kw))  # type: ignore[arg-type]
        if progress is not None:
            progress(i + 1, r.size)
    zd, zf = zoa_chart(modal, cut, r)
    return LobeChart(
        rpm=r,
        sd_depth=np.array([b.depth for b in bounds]),
        sd_kind=tuple(b.kind for b in bounds),
        zoa_depth=zd,
        zoa_freq_hz=zf,
    )


def stable(sd: SemiDiscretization, rpm: float, depth: float) -> tuple[bool, Multiplier]:
    """Whether the cut at ``(rpm, depth)`` is stable by ``sd``, and its critical multiplier."""
    mult = sd.multiplier(rpm, depth)
    return mult.modulus < 1.0, mult


__all__ = [
    "INTERVALS_PER_MODE_PERIOD",
    "Boundary",
    "LobeChart",
    "converged_boundary",
    "first_crossing",
    "intervals_for",
    "lobe_chart",
    "sd_boundary",
    "stable",
]
