r"""Inverse dynamic identification with least squares (IDIM-LS) of a rigid axis.

The reference is the EMPS benchmark (Janot, Gautier, Brunot, "Data Set and Reference
Models of EMPS", 2019; see ``../shared/data/README.md``): the inverse dynamic model

.. math::

    \tau = M \ddot q + F_v \dot q + F_c \,\mathrm{sign}(\dot q) + \tau_{off}

is linear in its parameters, so with the position low-pass filtered and differentiated
the parameters follow from ordinary least squares on the (decimated) samples. The
pipeline, each step a documented choice:

1. 4th-order Butterworth low-pass at 100 Hz on the position, run forward and backward
   (zero phase, ``filtfilt``) — the benchmark's "Butterworth, no phase shift".
2. Central differences for velocity and acceleration (``np.gradient``; one-sided at the
   two end samples, which are then dropped).
3. Parallel decimation by 10 of every regressor column and of the force: an 8th-order
   Chebyshev type-I low-pass (0.05 dB ripple, cut-off 0.8 of the new Nyquist frequency)
   run forward and backward, then every 10th sample, aligned so the last sample is kept.
   This is MATLAB's ``decimate`` (which the benchmark's scripts use); the alignment
   matters at the 0.1 % level on this file.
4. Ordinary least squares; relative error :math:`\|y - X\theta\| / \|y\|` on the
   decimated samples, as the benchmark reports it.

This module is pure numpy/scipy and batch (no per-sample recursion), so it has no numba
kernel; it takes measurements and returns estimates, never truth.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
import scipy.signal
from numpy.typing import ArrayLike, NDArray

from common.arrays import F64
from estimators.errors import ParameterError, require_positive

RIGID_NAMES: tuple[str, ...] = ("M", "Fv", "Fc", "offset")


@dataclass(frozen=True)
class IdimParams:
    """Filtering, differentiation and decimation settings of IDIM-LS.

    Parameters
    ----------
    cutoff_hz : float
        Cut-off of the Butterworth position low-pass [Hz] (benchmark: 100).
    order : int
        Order of the Butterworth low-pass (benchmark: 4).
    decimation : int
        Decimation factor (benchmark: 10); 1 disables decimation.
    decimation_order : int
        Order of the Chebyshev type-I anti-alias filter of the decimation (MATLAB: 8).
    """

    cutoff_hz: float = 100.0
    order: int = 4
    decimation: int = 10
    decimation_order: int = 8

    def __post_init__(self) -> None:
        require_positive("cutoff_hz", self.cutoff_hz)
        if not isinstance(self.order, int) or not 1 <= self.order <= 12:
            raise ParameterError("order", "an integer in [1, 12]", self.order)
        if not isinstance(self.decimation, int) or not 1 <= self.decimation <= 1000:
            raise ParameterError("decimation", "an integer in [1, 1000]", self.decimation)
        if not isinstance(self.decimation_order, int) or not 1 <= self.decimation_order <= 12:
            raise ParameterError("decimation_order", "an integer in [1, 12]", self.decimation_order)


@dataclass(frozen=True)
class Kinematics:
    """Filtered position and its central-difference derivatives, end samples dropped."""

    index: NDArray[np.int64]
    q: F64
    qd: F64
    qdd: F64


@dataclass(frozen=True, eq=False)
class IdimResult:
    """An IDIM-LS fit.

    Attributes
    ----------
    names : tuple of str
        Parameter names, in column order.
    theta : ndarray
        Estimated parameters.
    std : ndarray
        Their standard deviations (from the residual variance and ``(X^T X)^-1``).
    relerr : float
        ``||y - X theta|| / ||y||`` in % on the decimated fitting samples.
    rms : float
        RMS of ``y - X theta`` on the decimated fitting samples.
    n_samples : int
        Decimated samples used.
    """

    names: tuple[str, ...]
    theta: F64
    std: F64
    relerr: float
    rms: float
    n_samples: int
    extra: dict[str, float] = field(default_factory=dict)

    def as_dict(self) -> dict[str, float]:
        """Parameters by name."""
        return {n: float(v) for n, v in zip(self.names, self.theta)}


def _check_signal(name: str, x: ArrayLike, n: int | None = None) -> F64:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim != 1:
        raise ParameterError(name, "a 1-D array", f"shape {a.shape}")
    if n is not None and len(a) != n:
        raise ParameterError(name, f"{n} samples", len(a))
    if not np.all(np.isfinite(a)):
        raise ParameterError(name, "finite values", "NaN or inf")
    return a


def kinematics(q: ArrayLike, sample_time: float, params: IdimParams = IdimParams()) -> Kinematics:
    """Zero-phase low-pass the position and differentiate it twice (steps 1-2).

    Raises
    ------
    ParameterError
        If the cut-off is not below the Nyquist frequency or the record is too short.
    """
    ts = require_positive("sample_time", sample_time)
    qa = _check_signal("q", q)
    nyq = 0.5 / ts
    if params.cutoff_hz >= nyq:
        raise ParameterError(
            "cutoff_hz", f"a value < Nyquist frequency {nyq:g} Hz", params.cutoff_hz
        )
    # MATLAB filtfilt pads 3*(nfilt-1) = 3*order samples (odd reflection); scipy's default
    # is 3*(order+1). The benchmark ran MATLAB, so its padding is used here.
    pad = 3 * params.order
    if len(qa) <= max(pad, 4):
        raise ParameterError("q", f"more than {max(pad, 4)} samples", len(qa))
    b, a = scipy.signal.butter(params.order, params.cutoff_hz / nyq)
    qf = scipy.signal.filtfilt(b, a, qa, padlen=pad)
    # central differences (np.gradient is central inside, one-sided at the ends)
    qd = np.gradient(qf, ts)
    qdd = np.gradient(qd, ts)
    # the end samples carry one-sided differences: dropped
    idx = np.arange(1, len(qa) - 1)
    return Kinematics(idx, qf[idx], qd[idx], qdd[idx])


def decimate(x: ArrayLike, params: IdimParams = IdimParams()) -> F64:
    """Anti-alias filter (zero phase) and keep every ``decimation``-th sample (step 3).

    The kept samples end at the last sample, as MATLAB's ``decimate`` does.
    """
    xa = np.asarray(x, dtype=np.float64)
    r = params.decimation
    if r == 1:
        return xa.copy()
    n = xa.shape[0]
    pad = 3 * params.decimation_order
    if n <= pad:
        raise ParameterError("x", f"more than {pad} samples to decimate by {r}", n)
    b, a = scipy.signal.cheby1(params.decimation_order, 0.05, 0.8 / r)
    y = scipy.signal.filtfilt(b, a, xa, axis=0, padlen=pad)
    nout = -(-n // r)
    start = r - (r * nout - n) - 1
    return np.ascontiguousarray(y[start::r])


def decimated_index(n: int, params: IdimParams = IdimParams()) -> NDArray[np.int64]:
    """Indices (into an ``n``-sample record) of the samples :func:`decimate` keeps."""
    r = params.decimation
    if r == 1:
        return np.arange(n)
    nout = -(-n // r)
    return np.arange(r - (r * nout - n) - 1, n, r)


def rigid_regressor(qd: ArrayLike, qdd: ArrayLike) -> F64:
    r"""Regressor columns :math:`[\ddot q, \dot q, \mathrm{sign}(\dot q), 1]` of the rigid model."""
    v = np.asarray(qd, dtype=np.float64)
    acc = np.asarray(qdd, dtype=np.float64)
    return np.column_stack([acc, v, np.sign(v), np.ones_like(v)])


def least_squares(x: ArrayLike, y: ArrayLike, names: tuple[str, ...]) -> IdimResult:
    """Ordinary least squares with parameter standard deviations and relative error.

    Raises
    ------
    ParameterError
        If there are fewer samples than parameters or the regressor is rank deficient.
    """
    X = np.asarray(x, dtype=np.float64)
    Y = np.asarray(y, dtype=np.float64)
    n, p = X.shape
    if len(names) != p:
        raise ParameterError("names", f"{p} names", len(names))
    if n <= p:
        raise ParameterError("samples", f"more than {p} samples", n)
    theta, _, rank, _ = np.linalg.lstsq(X, Y, rcond=None)
    if rank < p:
        raise ParameterError("regressor", f"full column rank {p} (excited data)", int(rank))
    e = Y - X @ theta
    sigma2 = float(e @ e) / (n - p)
    cov = sigma2 * np.linalg.inv(X.T @ X)
    relerr = 100.0 * float(np.linalg.norm(e)) / max(float(np.linalg.norm(Y)), 1e-300)
    return IdimResult(
        names,
        np.asarray(theta, dtype=np.float64),
        np.sqrt(np.clip(np.diag(cov), 0.0, None)),
        relerr,
        float(np.sqrt(np.mean(e * e))),
        n,
    )


def idim_ls(
    q: ArrayLike,
    force: ArrayLike,
    sample_time: float,
    params: IdimParams = IdimParams(),
    *,
    extra: Mapping[str, ArrayLike] | None = None,
) -> IdimResult:
    """Identify the rigid model (plus optional extra regressor columns) by IDIM-LS.

    Parameters
    ----------
    q : array_like
        Position [m] or [rad], uniformly sampled.
    force : array_like
        Effort [N] or [N m], same samples.
    sample_time : float
        Sampling interval [s].
    params : IdimParams
        Pipeline settings.
    extra : mapping of str to array_like, optional
        Additional regressor columns over the same samples (full length); they are
        trimmed and decimated like the others.

    Returns
    -------
    IdimResult
    """
    qa = _check_signal("q", q)
    fa = _check_signal("force", force, len(qa))
    kin = kinematics(qa, sample_time, params)
    X = rigid_regressor(kin.qd, kin.qdd)
    names = list(RIGID_NAMES)
    if extra:
        cols = [X]
        for k, v in extra.items():
            cols.append(_check_signal(k, v, len(qa))[kin.index][:, None])
            names.append(k)
        X = np.hstack(cols)
    Xd = decimate(X, params)
    yd = decimate(fa[kin.index], params)
    return least_squares(Xd, yd, tuple(names))
