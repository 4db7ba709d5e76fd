r"""Shape searches and spectra shared by the residual models (pure numpy/scipy).

Least-squares cost of a few columns (:func:`project_rss`), a grid refined by a bounded
search (:func:`refine_grid`), the strongest period in position (:func:`search_period`)
or in time (:func:`search_frequency`, with :func:`gap_filled` for a training fold with
its validation rows cut out), and the structure left in a residual
(:func:`unexplained_structure`).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import minimize_scalar

from common.arrays import F64
from common.stats import rms

#: largest number of samples used by a shape search (the residual is subsampled)
SEARCH_SAMPLES = 50_000


def project_rss(cols: F64, r: F64) -> float:
    # normal equations: a few columns, well scaled (sin/cos, unit exponentials, ones)
    g = cols.T @ cols
    b = cols.T @ r
    if np.linalg.cond(g) < 1e10:
        coef = np.linalg.solve(g, b)
    else:  # near-singular (e.g. a vanishing Stribeck column): the robust solver
        coef, *_ = np.linalg.lstsq(cols, r, rcond=None)
        return float(np.sum((r - cols @ coef) ** 2))
    return float(r @ r - b @ coef)


def search_period(q: F64, r: F64, dq_min: float) -> tuple[float, float]:
    """Period in position of the strongest periodic component of ``r`` (grid + refine)."""
    span = float(np.ptp(q))
    lo = max(4.0 * dq_min, span * 1e-4, 1e-12)
    hi = span / 2.0
    if not hi > lo:
        return math.nan, math.inf
    grid = np.geomspace(lo, hi, 160)

    def rss(p: float) -> float:
        w = 2.0 * np.pi * q / p
        return project_rss(np.column_stack([np.cos(w), np.sin(w)]), r)

    vals = np.array([rss(p) for p in grid])
    k = int(np.argmin(vals))
    a, b = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
    fine = np.linspace(a, b, 41)
    fv = np.array([rss(p) for p in fine])
    j = int(np.argmin(fv))
    return float(fine[j]), float(fv[j])


def search_frequency(t: F64, r: F64, f_max: float = math.inf) -> tuple[float, float]:
    """Frequency [Hz] and amplitude of the largest spectral peak of ``r`` (zero-padded FFT)
    at or below ``f_max``."""
    n = len(r)
    if n < 16:
        return math.nan, 0.0
    dt = float(np.median(np.diff(t)))
    nfft = 1 << int(math.ceil(math.log2(4 * n)))
    win = np.hanning(n)
    spec = np.abs(np.fft.rfft((r - r.mean()) * win, nfft)) * 2.0 / win.sum()
    f = np.fft.rfftfreq(nfft, dt)
    # skip the lowest bins (below three cycles over the record: that is drift, not harmonic)
    spec[f < 3.0 / (n * dt)] = 0.0
    spec[f > f_max] = 0.0
    k = int(np.argmax(spec))
    return float(f[k]), float(spec[k])


def gap_filled(t: F64, r: F64, mask: NDArray[np.bool_]) -> tuple[F64, F64]:
    """``t`` and ``r`` over the span of the ``mask`` samples, ``r`` minus its mean there
    and zero outside the mask: a spectrum of training rows with a validation fold cut
    out keeps its time axis (dropping the rows would make the phase jump at the gap)."""
    idx = np.flatnonzero(mask)
    if len(idx) == 0:
        return t[:0], r[:0]
    a, b = int(idx[0]), int(idx[-1]) + 1
    m = mask[a:b]
    rr = np.where(m, r[a:b] - float(np.mean(r[idx])), 0.0)
    return t[a:b], np.asarray(rr, dtype=np.float64)


def refine_grid(cost: Callable[[float], float], grid: F64, *, log: bool = False) -> float:
    """The minimiser of ``cost`` over ``grid``, refined between the grid neighbours of the
    best point (bounded Brent search, in log scale with ``log``).

    A coarse grid alone leaves a shape error (a 10 ms delay on a 17 % geometric grid is
    off by up to 8 %) whose residual then passes as a second "effect" (a drive delay
    after the delay, on long records)."""
    vals = np.array([cost(float(g)) for g in grid])
    if not np.any(np.isfinite(vals)):
        return math.nan
    k = int(np.nanargmin(vals))
    lo, hi = float(grid[max(k - 1, 0)]), float(grid[min(k + 1, len(grid) - 1)])
    if not hi > lo:
        return float(grid[k])
    if log:
        res = minimize_scalar(
            lambda u: cost(math.exp(u)), bounds=(math.log(lo), math.log(hi)), method="bounded",
            options={"xatol": 1e-3},
        )  # fmt: skip
        x = math.exp(float(res.x))
    else:
        res = minimize_scalar(cost, bounds=(lo, hi), method="bounded")
        x = float(res.x)
    return x if float(res.fun) <= float(vals[k]) else float(grid[k])


def unexplained_structure(
    t: F64, q: F64, residual: F64, *, prominence: float = 6.0, min_ratio: float = 0.15
) -> list[dict[str, float | str]]:
    """The largest periodic structure left in ``residual``, in time and in position.

    A peak is reported when its amplitude is at least ``prominence`` times the median
    amplitude of its spectrum and at least ``min_ratio`` times the residual's rms.
    """
    out: list[dict[str, float | str]] = []
    level = rms(residual)
    if level == 0.0:
        return out
    freq, amp = search_frequency(t, residual)
    n = len(residual)
    win = np.hanning(n)
    spec = np.abs(np.fft.rfft((residual - residual.mean()) * win)) * 2.0 / win.sum()
    med = float(np.median(spec[1:])) if len(spec) > 1 else 0.0
    if math.isfinite(freq) and amp >= prominence * med and amp >= min_ratio * level:
        out.append(
            {"domain": "time", "frequency_hz": freq, "amplitude": amp, "ratio_to_rms": amp / level}
        )
    stride = max(1, int(math.ceil(n / SEARCH_SAMPLES)))
    qs, r = q[::stride], residual[::stride] - residual.mean()
    dq = float(np.median(np.abs(np.diff(q)))) if n > 1 else 0.0
    period, _ = search_period(qs, r, dq)
    if math.isfinite(period):
        w = 2.0 * np.pi * qs / period
        cols = np.column_stack([np.cos(w), np.sin(w)])
        coef, *_ = np.linalg.lstsq(cols, r, rcond=None)
        pamp = float(math.hypot(coef[0], coef[1]))
        if pamp >= min_ratio * level:
            out.append(
                {
                    "domain": "position",
                    "period": period,
                    "amplitude": pamp,
                    "ratio_to_rms": pamp / level,
                }
            )
    return out
