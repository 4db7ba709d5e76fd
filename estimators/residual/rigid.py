r"""The rigid residual model: IDIM-LS of a one-position axis and its effect families.

The nominal model is the rigid inverse dynamic model of :mod:`estimators.idim`,
identified by IDIM-LS on the fitting part of the record (the first
``1 - holdout_fraction``). Each candidate effect is a family of extra regressor columns
(the registry :data:`FAMILIES`, :mod:`estimators.residual.families`: the canonical
families and the real-drive ones) whose *shape* parameters (period, frequency, velocity
scale, delay) are searched on the residual; its *linear* coefficients are refitted
jointly with the nominal parameters. :class:`RigidModel` is this model as the engine
(:func:`estimators.residual.engine.analyse`) uses it: the selection is blocked
cross-validation over the fitting part (:mod:`estimators.residual.selection`); the
held-out end is the report figure (``rms_*``, ``relerr_*`` on its decimated samples).

Columns already spanned by the current model (e.g. ``offset`` in the rigid nominal, or
``1[v>0]`` given ``sign(v)`` and an offset) are dropped before fitting, so a family
that adds nothing new scores no gain. ``torque_ripple`` (motor angle) and ``backlash``
need a load-side position; they are not offered for a one-position rigid log.

The sampling-rate-dependent choices are the model's: the position filter and the
decimation (``idim``, default :func:`idim_for_rate`), the least record length
(:data:`ROWS_PER_BLOCK` decimated rows per block) and the families offered
(``families``).

Pure numpy/scipy (batch; no per-sample recursion, so no numba kernel).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike, NDArray

from common.arrays import F64
from common.stats import rms
from estimators.errors import ParameterError
from estimators.idim import (
    RIGID_NAMES,
    IdimParams,
    decimate,
    decimated_index,
    kinematics,
    rigid_regressor,
)
from estimators.residual.engine import (
    Effect,
    Extension,
    ResidualParams,
    ResidualResult,
    Rows,
    Selection,
    Shape,
)
from estimators.residual.families import FAMILIES as REGISTRY
from estimators.residual.families import LOAD, OFFERED, Family, SearchData
from estimators.residual.rate import column_kinematics, rate_plan
from estimators.residual.selection import Fold, OutOfFold, SelectionParams, support
from estimators.residual.shapes import SEARCH_SAMPLES, unexplained_structure

#: the rigid model's family registry (estimators.residual.families: one entry per family)
FAMILIES: Mapping[str, Family] = OFFERED
#: canonical families (docs/design.md) not offered for a rigid one-position log, with the
#: reason
NOT_OFFERED: dict[str, str] = {
    "torque_ripple": "needs motor and load positions (q_l) to separate from position_periodic",
    "backlash": "needs a load-side position (q_l)",
}
#: samples of a shape search inside a fold
_FOLD_SEARCH = 20_000
#: least decimated rows of a record per block of ResidualParams.blocks
ROWS_PER_BLOCK = 40


def idim_for_rate(sample_time: float) -> IdimParams:
    """The filtering and decimation of the nominal fit for a record sampled every
    ``sample_time`` seconds (:func:`estimators.residual.rate.rate_plan`: the benchmark's
    pipeline at 1 kHz and above, its proportions below)."""
    return rate_plan(sample_time).idim


@dataclass(frozen=True)
class Signals:
    """Full-rate signals on the samples kept by the differentiation (ends dropped)."""

    t: F64
    q: F64
    qd: F64
    qdd: F64
    qddd: F64
    force: F64
    #: 1 on the rows where a process load acts (``--load-rows``), else None
    load: F64 | None = None


def signals(
    q: ArrayLike, force: ArrayLike, t: ArrayLike, sample_time: float, p: IdimParams | None = None
) -> Signals:
    """Filter and differentiate the position (IDIM pipeline) and align ``t`` and ``force``."""
    p = IdimParams() if p is None else p
    kin = kinematics(q, sample_time, p)
    qddd = np.gradient(kin.qdd, sample_time)
    ta = np.asarray(t, dtype=np.float64)
    fa = np.asarray(force, dtype=np.float64)
    return Signals(ta[kin.index], kin.q, kin.qd, kin.qdd, qddd, fa[kin.index])


def _full_rate(values: F64, n: int, index: NDArray[np.int64] | None = None) -> F64:
    """Extend a series over the samples ``index`` (default 1..n-2) to 0..n-1: samples
    between are interpolated, the ends repeat their neighbour."""
    if index is None:
        out = np.empty(n)
        out[1:-1] = values
        out[0], out[-1] = values[0], values[-1]
        return out
    return np.interp(np.arange(n, dtype=np.float64), index.astype(np.float64), values)


@dataclass(frozen=True, eq=False)
class Design:
    """Decimated regressor, force and the full-rate columns of one model structure.

    The full-rate matrix (a million rows and more) is joined from its blocks when first
    read: most structures the selection builds are only fitted on the decimated rows.
    """

    names: tuple[str, ...]
    x_dec: F64
    full_blocks: tuple[F64, ...]

    @cached_property
    def x_full(self) -> F64:
        """The full-rate columns, one matrix."""
        return np.hstack(self.full_blocks)


def build_design(
    sig: Signals,
    effects: tuple[Effect, ...],
    p: IdimParams,
    cache: dict[tuple[str, tuple[tuple[str, float], ...]], tuple[F64, F64]] | None = None,
) -> Design:
    """Regressor of the nominal model plus ``effects``; decimated blocks are cached."""
    cache = {} if cache is None else cache
    full = []
    dec = []
    names = list(RIGID_NAMES)
    keys: list[tuple[str, tuple[tuple[str, float], ...]]] = [("__rigid__", ())]
    keys.extend((e.name, tuple(sorted(e.shape.items()))) for e in effects)
    for key, e in zip(keys, (None, *effects)):
        if key not in cache:
            c = rigid_regressor(sig.qd, sig.qdd) if e is None else effect_columns(e, sig)
            cache[key] = (c, decimate(c, p))
        full.append(cache[key][0])
        dec.append(cache[key][1])
        if e is not None:
            names.extend(f"{e.name}.{cn}" for cn in e.columns)
    return Design(tuple(names), np.hstack(dec), tuple(full))


def _independent(x: F64, base: int, fit: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """Keep mask of columns: base columns always; later ones if not spanned by the kept."""
    keep = np.zeros(x.shape[1], dtype=bool)
    keep[:base] = True
    xf = x[fit]
    for j in range(base, x.shape[1]):
        c = xf[:, j]
        nc = float(np.linalg.norm(c))
        if nc == 0.0:
            continue
        a = xf[:, keep]
        coef, *_ = np.linalg.lstsq(a, c, rcond=None)
        if float(np.linalg.norm(c - a @ coef)) > 1e-6 * nc:
            keep[j] = True
    return keep


def fit_design(design: Design, y_dec: F64, fit: NDArray[np.bool_]) -> tuple[F64, NDArray[np.bool_]]:
    """Least squares on the fitting samples; returns theta (0 for dropped columns), keep."""
    keep = _independent(design.x_dec, len(RIGID_NAMES), fit)
    theta = np.zeros(design.x_dec.shape[1])
    sol, *_ = np.linalg.lstsq(design.x_dec[fit][:, keep], y_dec[fit], rcond=None)
    theta[keep] = sol
    return theta, keep


def _guard_rows(sample_time: float, p: IdimParams) -> int:
    """Decimated rows around a validation fold left out of training: ten time constants
    of the slowest filter of the IDIM pipeline (position low-pass or anti-alias)."""
    fs = 1.0 / sample_time
    slowest = min(p.cutoff_hz, 0.4 * fs / p.decimation)
    return int(math.ceil(10.0 / (2.0 * math.pi * slowest) / (sample_time * p.decimation))) + 2


def _rigid_oof(
    x_cur: F64,
    cand: F64 | list[F64],
    y: F64,
    folds: list[Fold],
    before: list[F64],
    sp: SelectionParams,
) -> OutOfFold:
    """Out-of-fold errors before/after the candidate columns (one matrix, or one per
    fold when its shape was searched inside the fold) and the verdict."""
    n_fit = int(sum(int(fd.val.sum()) for fd in folds))
    sq0, sq1 = np.empty(n_fit), np.empty(n_fit)
    supp = np.zeros(n_fit, dtype=bool)
    nc = x_cur.shape[1]
    for k, (fd, th0) in enumerate(zip(folds, before)):
        c = cand[k] if isinstance(cand, list) else cand
        x = np.hstack([x_cur, c])
        keep = _independent(x, nc, fd.train)
        th = np.zeros(x.shape[1])
        # unit-norm columns and a relative cut-off: a candidate nearly spanned by the
        # nominal columns on the training rows (a harmonic at the motion's frequency)
        # must not get huge opposite coefficients that explode on the validation fold
        xt = x[fd.train][:, keep]
        nrm = np.linalg.norm(xt, axis=0)
        nrm[nrm == 0.0] = 1.0
        sol, *_ = np.linalg.lstsq(xt / nrm, y[fd.train], rcond=1e-6)
        th[keep] = sol / nrm
        term = c @ th[nc:]
        v = np.flatnonzero(fd.val)
        sq0[v] = (y[v] - x_cur[v] @ th0) ** 2
        sq1[v] = (y[v] - x[v] @ th) ** 2
        supp[v] = support(term[fd.train], term[v], sp.support_level)
    return OutOfFold(sq0, sq1, supp)


def effect_columns(effect: Effect, sig: Signals) -> F64:
    """Regressor columns of ``effect`` over the samples of ``sig`` (shape ``(n, k)``)."""
    fam = REGISTRY.get(effect.name)
    if fam is None:
        raise ParameterError("effect", f"one of {', '.join(REGISTRY)}", effect.name)
    return fam.columns(effect.shape, sig)


def find_shape(
    name: str,
    sig: Signals,
    residual: F64,
    mask: NDArray[np.bool_],
    nominal: F64 | None = None,
    max_samples: int = SEARCH_SAMPLES,
    decimation: int = 1,
) -> Shape:
    """Shape parameters of family ``name`` from the residual on ``mask`` samples
    (searched on at most ``max_samples`` of them, evenly spaced).

    ``nominal`` (M, Fv, Fc, offset of the current model) is needed by ``delay``;
    ``decimation`` (of the regressor) bounds the harmonic's frequency.
    """
    idx = np.flatnonzero(mask)
    stride = max(1, int(math.ceil(len(idx) / max_samples)))
    idx = idx[::stride]
    data = SearchData(sig, residual, mask, idx, residual[idx], nominal, decimation)
    return REGISTRY[name].search(data)


def effect_params(effect: Effect, design: Design, theta: F64) -> dict[str, float]:
    """Shape, fitted coefficients and derived figures of ``effect`` in a fitted design."""
    out = dict(effect.shape)
    byname = dict(zip(design.names, theta))
    for cn in effect.columns:
        out[cn] = float(byname.get(f"{effect.name}.{cn}", 0.0))
    out.update(REGISTRY[effect.name].derived(effect.shape, out, byname))
    return out


@dataclass(eq=False)
class RigidFit:
    """A model structure (nominal plus ``effects``) fitted on the fitting part."""

    effects: tuple[Effect, ...]
    design: Design
    theta: F64
    e_hold: F64  # error on the held-out decimated rows
    force: F64  # the record's effort (full rate)

    @cached_property
    def residual(self) -> F64:
        """Full-rate residual (the shape searches work on it)."""
        return np.asarray(self.force - self.design.x_full @ self.theta, dtype=np.float64)


class RigidModel:
    """The rigid axis :math:`\\tau = M\\ddot q + F_v\\dot q + F_c\\,\\mathrm{sign}(\\dot q) +
    \\tau_{off}` by IDIM-LS (:mod:`estimators.idim`) as a residual model for
    :func:`estimators.residual.engine.analyse`.

    Parameters
    ----------
    q, force, t : array_like
        Position, effort and time, uniformly sampled, same length.
    sample_time : float
        Sampling interval [s].
    idim : IdimParams, optional
        Filtering / decimation of the nominal fit (None: :func:`idim_for_rate`).
    families : mapping, optional
        The family registry (None: :data:`FAMILIES`, every family the model offers);
        a record that cannot identify some families (too slow a rate) gets fewer.
    rows_per_block : int
        Least decimated rows per block of ``ResidualParams.blocks`` (the least record
        length).
    qd, qdd : array_like, optional
        The controller's velocity and acceleration: used instead of filtering and
        differentiating the position (``qdd`` without ``qd`` is ignored).
    segments : array_like of int, optional
        Start index of each run of consecutive samples (a row selection cuts the
        record): nothing is differentiated across a cut.
    load : array_like of bool, optional
        Rows where a process load acts: offers the ``load`` family.
    nominal_rows : array_like of bool, optional
        Rows the nominal model (the report's "before") is fitted on, inside the fitting
        part (e.g. the tool in the air); the selection and the final model use every
        fitting row.
    """

    kind = "rigid"
    description = "rigid: tau = M*qdd + Fv*qd + Fc*sign(qd) + offset (IDIM-LS)"
    max_effects = 6  # a cap; a real drive (EMPS) needs 5

    def __init__(
        self,
        q: ArrayLike,
        force: ArrayLike,
        t: ArrayLike,
        sample_time: float,
        idim: IdimParams | None = None,
        families: Mapping[str, Family] | None = None,
        rows_per_block: int = ROWS_PER_BLOCK,
        *,
        qd: ArrayLike | None = None,
        qdd: ArrayLike | None = None,
        segments: ArrayLike | None = None,
        load: ArrayLike | None = None,
        nominal_rows: ArrayLike | None = None,
    ) -> None:
        self.q = np.asarray(q, dtype=np.float64)
        self.rows_per_block = rows_per_block
        self.force, self.t, self.sample_time = force, t, sample_time
        self.p = idim_for_rate(sample_time) if idim is None else idim
        fams = dict(FAMILIES if families is None else families)
        self.not_offered: Mapping[str, str] = NOT_OFFERED
        if load is None:
            fams.pop(LOAD.name, None)
            self.not_offered = {
                **NOT_OFFERED,
                LOAD.name: "needs the rows where the load acts (--load-rows)",
            }
        elif families is None:
            fams[LOAD.name] = LOAD
        self.families: Mapping[str, Family] = fams
        self.qd = None if qd is None else np.asarray(qd, dtype=np.float64)
        self.qdd = None if qdd is None or qd is None else np.asarray(qdd, dtype=np.float64)
        self.segments = None if segments is None else np.asarray(segments, dtype=np.int64)
        self.load = None if load is None else np.asarray(load, dtype=bool)
        self.nominal_rows = None if nominal_rows is None else np.asarray(nominal_rows, dtype=bool)
        self._cache: dict[tuple[str, tuple[tuple[str, float], ...]], tuple[F64, F64]] = {}

    @cached_property
    def index(self) -> NDArray[np.int64]:
        """The record's rows the signals keep (the differentiation drops ends)."""
        if self.qd is None:
            return np.arange(1, len(self.q) - 1)
        return column_kinematics(self.q, self.qd, self.qdd, self.sample_time, self.segments)[0]

    @cached_property
    def sig(self) -> Signals:
        """The signals: filtered and differentiated position (IDIM pipeline), or the
        controller's velocity and acceleration columns when given."""
        if self.qd is None:
            s = signals(self.q, self.force, self.t, self.sample_time, self.p)
        else:
            idx, q, qd, qdd, qddd = column_kinematics(
                self.q, self.qd, self.qdd, self.sample_time, self.segments
            )
            ta = np.asarray(self.t, dtype=np.float64)
            fa = np.asarray(self.force, dtype=np.float64)
            s = Signals(ta[idx], q, qd, qdd, qddd, fa[idx])
        if self.load is not None:
            s = replace(s, load=self.load[self.index].astype(np.float64))
        return s

    @cached_property
    def di(self) -> NDArray[np.int64]:
        return decimated_index(len(self.sig.t), self.p)

    @cached_property
    def y_dec(self) -> F64:
        return decimate(self.sig.force, self.p)

    def prepare(self, params: ResidualParams, say: Callable[[str], None]) -> Rows:
        """Check the length, split the decimated rows into fitting part and held-out end."""
        n, p = len(self.q), self.p
        min_dec = self.rows_per_block * params.blocks
        if n < 3 + p.decimation * min_dec:
            raise ParameterError(
                "samples",
                f"at least {3 + p.decimation * min_dec} samples for the held-out split "
                f"({min_dec} decimated samples)",
                n,
            )
        t_dec = self.sig.t[self.di]
        split = int(round((1.0 - params.holdout_fraction) * len(t_dec)))
        self.fit = np.zeros(len(t_dec), dtype=bool)
        self.fit[:split] = True
        self.hold = ~self.fit
        if self.hold.sum() < 4 * params.blocks or self.fit.sum() < 20:
            raise ParameterError(
                "samples",
                "enough decimated samples on both sides of the split",
                int(self.hold.sum()),
            )
        # full-rate mask of the fitting part (for shape searches)
        self.fit_full = self.sig.t < t_dec[split]
        # full-rate sample -> its decimated row (for the shape searches inside a fold)
        self.row_of = np.clip(np.searchsorted(t_dec, self.sig.t), 0, len(t_dec) - 1)
        say("nominal fit")
        # the controller's velocity, undecimated: no filter memory to guard against
        guard = 2 if self.qd is not None and p.decimation == 1 else _guard_rows(self.sample_time, p)
        return Rows(len(t_dec), split, guard)

    def _fitted(self, effects: tuple[Effect, ...]) -> RigidFit:
        d = build_design(self.sig, effects, self.p, self._cache)
        theta, _ = fit_design(d, self.y_dec, self.fit)
        return RigidFit(
            effects, d, theta, self.y_dec[self.hold] - d.x_dec[self.hold] @ theta, self.sig.force
        )

    def nominal(self) -> RigidFit:
        if self.nominal_rows is None:
            return self._fitted(())
        # the nominal model on the chosen rows of the fitting part (decimated rows: the
        # row each decimated sample stands for)
        rows = self.nominal_rows[self.index][self.di] & self.fit
        if rows.sum() < 10:
            raise ParameterError(
                "nominal_rows", "at least 10 rows in the fitting part", int(rows.sum())
            )
        d = build_design(self.sig, (), self.p, self._cache)
        theta, _ = fit_design(d, self.y_dec, rows)
        return RigidFit((), d, theta, self.y_dec[self.hold] - d.x_dec[self.hold] @ theta,
                        self.sig.force)  # fmt: skip

    def holdout_mse(self, state: RigidFit) -> float:
        return float(np.mean(state.e_hold**2))

    def holdout_rms(self, state: RigidFit) -> float:
        return rms(state.e_hold)

    def search(self, name: str, state: RigidFit, fold: tuple[Fold, F64] | None = None) -> Shape:
        if fold is None:
            return find_shape(
                name, self.sig, state.residual, self.fit_full, state.theta[:4],
                decimation=self.p.decimation,
            )  # fmt: skip
        fd, th_k = fold
        r_k = self.sig.force - state.design.x_full @ th_k
        return find_shape(
            name, self.sig, r_k, fd.train[self.row_of], th_k[:4], _FOLD_SEARCH, self.p.decimation
        )

    def extend(self, state: RigidFit, name: str, shape: Shape) -> Extension[RigidFit, F64]:
        eff = Effect(name, shape, self.families[name].column_names(shape))
        d = build_design(self.sig, (*state.effects, eff), self.p, self._cache)
        th, keep = fit_design(d, self.y_dec, self.fit)
        new = RigidFit(
            (*state.effects, eff),
            d,
            th,
            self.y_dec[self.hold] - d.x_dec[self.hold] @ th,
            self.sig.force,
        )
        nc = len(state.design.names)
        return Extension(
            state=new,
            columns=d.x_dec[:, nc:],
            added=int(keep[nc:].sum()),
            ncols=len(eff.columns),
            term=d.x_dec[self.fit][:, nc:] @ th[nc:],
            params=effect_params(eff, d, th),
        )

    def columns(self, name: str, shape: Shape) -> F64:
        return decimate(self.families[name].columns(shape, self.sig), self.p)

    def fold_fits(self, state: RigidFit, folds: list[Fold]) -> list[F64]:
        return [fit_design(state.design, self.y_dec, fd.train)[0] for fd in folds]

    def out_of_fold(
        self,
        state: RigidFit,
        folds: list[Fold],
        before: list[F64],
        cols: F64 | list[F64],
        sp: SelectionParams,
    ) -> OutOfFold:
        return _rigid_oof(state.design.x_dec, cols, self.y_dec, folds, before, sp)

    def selected_params(self, state: RigidFit, index: int) -> dict[str, float]:
        return effect_params(state.effects[index], state.design, state.theta)

    def result(
        self, nominal: RigidFit, final: RigidFit, sel: Selection, say: Callable[[str], None]
    ) -> ResidualResult:
        say("unexplained structure")
        sig, di, y_dec, n = self.sig, self.di, self.y_dec, len(self.q)
        design0, theta0, design, theta = nominal.design, nominal.theta, final.design, final.theta
        resid_after_full = sig.force - design.x_full @ theta
        hold_full = ~self.fit_full
        unexpl = unexplained_structure(
            sig.t[hold_full], sig.q[hold_full], resid_after_full[hold_full]
        )
        y_h = y_dec[self.hold]
        norm_y = max(float(np.linalg.norm(y_h)), 1e-300)
        t_dec = sig.t[di]
        byname = dict(zip(design.names, map(float, theta)))
        effects = tuple(
            Effect(e.name, e.shape, e.columns, tuple(byname[f"{e.name}.{c}"] for c in e.columns))
            for e in final.effects
        )
        e0, e1 = nominal.e_hold, final.e_hold
        terms: dict[str, F64] = {}
        col = dict(zip(design.names, range(len(design.names))))
        for e in final.effects:
            j = [col[f"{e.name}.{c}"] for c in e.columns]
            terms[e.name] = design.x_dec[:, j] @ theta[j]
        return ResidualResult(
            kind=self.kind,
            model=self.description,
            names_before=design0.names,
            theta_before=theta0,
            names_after=design.names,
            theta_after=theta,
            effects=effects,
            candidates=sel.candidates,
            holdout_start=float(t_dec[sel.rows.split]),
            holdout_stop=float(t_dec[-1]),
            rms_before=rms(e0),
            rms_after=rms(e1),
            relerr_before=100.0 * float(np.linalg.norm(e0)) / norm_y,
            relerr_after=100.0 * float(np.linalg.norm(e1)) / norm_y,
            unexplained=tuple(unexpl),
            f_hat_before=_full_rate(design0.x_full @ theta0, n, self.index),
            f_hat_after=_full_rate(design.x_full @ theta, n, self.index),
            t_dec=t_dec,
            residual_before_dec=y_dec - design0.x_dec @ theta0,
            residual_after_dec=y_dec - design.x_dec @ theta,
            q_dec=sig.q[di],
            qd_dec=sig.qd[di],
            not_offered=dict(self.not_offered),
            indistinguishable=sel.indistinguishable,
            selection=sel.selection,
            hold_sq_before=e0**2,
            hold_sq_after=e1**2,
            hold_speed=sig.qd[di][self.hold],
            hold_sq_force_before=e0**2,
            hold_sq_force_after=e1**2,
            terms_dec=terms,
        )

    def evaluate(self, result: ResidualResult) -> dict[str, float]:
        """Held-out numbers of ``result``'s models (before/after) on this record: every
        decimated sample (none of it was fitted)."""
        y = self.y_dec
        d0 = build_design(self.sig, (), self.p)
        d1 = build_design(self.sig, result.effects, self.p)
        e0 = y - d0.x_dec @ result.theta_before
        e1 = y - d1.x_dec @ result.theta_after
        ny = max(float(np.linalg.norm(y)), 1e-300)
        return {
            "rms_before": rms(e0),
            "rms_after": rms(e1),
            "relerr_before": 100.0 * float(np.linalg.norm(e0)) / ny,
            "relerr_after": 100.0 * float(np.linalg.norm(e1)) / ny,
        }
