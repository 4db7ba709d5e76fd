r"""Cross-validated figures of a rigid residual model inside one record.

A model structure (the nominal rigid model plus a set of effects with their shapes fixed)
is refitted on part of the record and scored on the rest, with the benchmark's measure
:math:`\|y - X\theta\| / \|y\|` in % on the decimated samples of the scored part:

* **blocked folds**: the record is cut into ``folds`` contiguous blocks of equal length
  (on EMPS, 4 blocks = its 4 back-and-forth cycles); each block is predicted by the
  model fitted on the others, minus a guard of ``guard_s`` seconds on each side of the
  block (the anti-alias filter of the decimation and the position filter have memory);
* **acceleration split**: fitted on the samples whose :math:`|\ddot q|` is below its
  ``accel_quantile`` quantile, scored on the others (a proxy for a record with harder
  accelerations than the one fitted).

Pure numpy; the columns are those of :mod:`estimators.residual.rigid`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from common.arrays import F64
from estimators.errors import ParameterError, require_in
from estimators.idim import IdimParams, decimate, decimated_index
from estimators.residual.engine import Effect
from estimators.residual.rigid import build_design, signals


@dataclass(frozen=True)
class CvResult:
    """Relative errors [%] of a model structure refitted on parts of a record."""

    fold_relerr: tuple[float, ...]
    cv_relerr: float
    fit_relerr: float
    accel_relerr: float
    fold_bounds: tuple[tuple[float, float], ...]


def _relerr(e: F64, y: F64) -> float:
    return 100.0 * float(np.linalg.norm(e)) / max(float(np.linalg.norm(y)), 1e-300)


def _solve(x: F64, y: F64, rows: NDArray[np.bool_]) -> F64:
    sol, *_ = np.linalg.lstsq(x[rows], y[rows], rcond=None)
    return np.asarray(sol, dtype=np.float64)


def cross_validate(
    q: ArrayLike,
    force: ArrayLike,
    t: ArrayLike,
    sample_time: float,
    effects: Sequence[Effect] = (),
    *,
    folds: int = 4,
    guard_s: float = 0.2,
    accel_quantile: float = 0.7,
    p: IdimParams | None = None,
) -> CvResult:
    """Blocked-fold and acceleration-split relative errors of nominal + ``effects``.

    Raises
    ------
    ParameterError
        If ``folds`` is not an integer >= 2 or a fold is left without fitting samples.
    """
    if not isinstance(folds, int) or folds < 2:
        raise ParameterError("folds", "an integer >= 2", folds)
    require_in("accel_quantile", accel_quantile, 0.05, 0.95)
    p = IdimParams() if p is None else p
    sig = signals(q, force, t, sample_time, p)
    y = decimate(sig.force, p)
    design = build_design(sig, tuple(effects), p)
    x = design.x_dec
    td = sig.t[decimated_index(len(sig.t), p)]
    edges = np.linspace(td[0], td[-1], folds + 1)
    edges[-1] = np.inf
    err = np.zeros_like(y)
    per = []
    bounds = []
    for k in range(folds):
        te = (td >= edges[k]) & (td < edges[k + 1])
        tr = (td < edges[k] - guard_s) | (td >= edges[k + 1] + guard_s)
        if tr.sum() <= x.shape[1]:
            raise ParameterError("folds", "folds leaving enough fitting samples", folds)
        th = _solve(x, y, tr)
        err[te] = y[te] - x[te] @ th
        per.append(_relerr(err[te], y[te]))
        bounds.append((float(td[te][0]), float(td[te][-1])))
    all_rows = np.ones(len(y), dtype=bool)
    fit_err = y - x @ _solve(x, y, all_rows)
    acc = np.abs(sig.qdd[decimated_index(len(sig.t), p)])
    lo = acc < np.quantile(acc, accel_quantile)
    acc_err = y[~lo] - x[~lo] @ _solve(x, y, lo)
    return CvResult(
        fold_relerr=tuple(per),
        cv_relerr=_relerr(err, y),
        fit_relerr=_relerr(fit_err, y),
        accel_relerr=_relerr(acc_err, y[~lo]),
        fold_bounds=tuple(bounds),
    )
