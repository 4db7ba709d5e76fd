r"""Residual analysis of a rigid axis: candidate effects, held-out scoring, greedy selection.

The nominal model is the rigid inverse dynamic model of :mod:`estimators.idim`,
identified by IDIM-LS on the first part of the record (``1 - holdout_fraction``). Each
candidate effect is a parametric family of extra regressor columns whose *shape*
parameters (period, frequency, velocity scale) are found from the data of the fitting
part; its *linear* coefficients are refitted jointly with the nominal parameters. A
candidate is scored by the error on the held-out part only.

Greedy selection from cross-validation over the fitting part (the rule, its numbers and
its reasons: :mod:`estimators.residual_selection` and docs/residual-selection.md): per
round, every candidate is scored by blocked K-fold cross-validation with its shape
searched again inside each training fold; the effect it removes on its support, relative
to the floor, is tested across groups of support rows (Holm over the round's candidates)
and must reach a minimum size. The best accepted candidate is added; same-signal rivals
are reported as indistinguishable. The held-out end takes no part in the selection: it
is the final report figure (``rms_*``, ``relerr_*``).

Selection stops when no candidate passes or after ``max_effects`` effects. What is left
is summarised as ``unexplained`` structure: the largest peak of the residual's spectrum
in time and in position, with amplitude, when it stands out of the spectrum.

Families (canonical names of DESIGN) and their columns, with :math:`v = \dot q`:

================== ========================================================= ==========
name               columns                                                   shape
================== ========================================================= ==========
offset             :math:`1`                                                 —
inertia            :math:`\ddot q`                                           —
viscous            :math:`v`                                                 —
coulomb_asymmetry  :math:`1[v>0]`, :math:`|v|` (direction-dependent friction) —
stribeck           :math:`\mathrm{sign}(v)\,e^{-(|v|/v_s)^2}`                :math:`v_s`
position_periodic  :math:`\cos, \sin(2\pi k q / P)`, k = 1, 2                :math:`P`
harmonic           :math:`\cos, \sin(2\pi f t)`                              :math:`f`
delay              :math:`P(t-d) - P(t)`, P the nominal model's effort with
                   the nominal parameters at the search (the effort acts
                   late by d; coefficient 1 = the whole effort delayed)      d
drift              :math:`(t - t_0) / T`                                     —
================== ========================================================= ==========

Columns already spanned by the current model (e.g. ``offset`` in the rigid nominal, or
``1[v>0]`` given ``sign(v)`` and an offset) are dropped before fitting, so a family
that adds nothing new scores no gain. ``torque_ripple`` (motor angle) and ``backlash``
need a load-side position; they are not offered for a one-position rigid log.

Pure numpy/scipy (batch; no per-sample recursion, so no numba kernel).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import minimize_scalar

from common.arrays import F64
from common.stats import rms
from estimators import residual_families as _families
from estimators.errors import ParameterError, require_in
from estimators.idim import (
    RIGID_NAMES,
    IdimParams,
    decimate,
    decimated_index,
    kinematics,
    rigid_regressor,
)
from estimators.residual_selection import (
    Fold,
    OutOfFold,
    SelectionParams,
    Verdict,
    ambiguity,
    correlation,
    holm,
    make_folds,
    support,
    verdict,
)

# ---- THE CANDIDATE LIST of analyse_rigid (the one place to register a family: its name
# here, its columns in effect_columns/_columns_names, its shape search in find_shape;
# families with a shape go into _SHAPED_RIGID so the folds search it again) ----
FAMILIES: tuple[str, ...] = (
    "offset",
    "inertia",
    "viscous",
    "coulomb_asymmetry",
    "stribeck",
    "position_periodic",
    "harmonic",
    "delay",
    "drift",
    *_families.NAMES,  # real-drive families (estimators.residual_families)
)
#: families of DESIGN not offered for a rigid one-position log, with the reason
NOT_OFFERED: dict[str, str] = {
    "torque_ripple": "needs motor and load positions (q_l) to separate from position_periodic",
    "backlash": "needs a load-side position (q_l)",
}
#: largest number of samples used by a shape search (the residual is subsampled)
_SEARCH_SAMPLES = 50_000


@dataclass(frozen=True)
class ResidualParams:
    """Settings of the residual analysis.

    Parameters
    ----------
    holdout_fraction : float
        Fraction of the record, at its end, held out for scoring (0.05 ... 0.7).
    blocks : int
        Sets the least record length (40 decimated samples per block, >= 3).
    max_effects : int
        Most effects added.
    families : tuple of str
        Families offered (subset of :data:`FAMILIES`).
    idim : IdimParams
        Filtering / decimation of the IDIM-LS pipeline.
    selection : SelectionParams
        The cross-validated decision rule.
    """

    holdout_fraction: float = 0.3
    blocks: int = 10
    max_effects: int = 6  # a cap; a real drive (EMPS) needs 5
    families: tuple[str, ...] = FAMILIES
    idim: IdimParams = field(default_factory=IdimParams)
    selection: SelectionParams = field(default_factory=SelectionParams)

    def __post_init__(self) -> None:
        require_in("holdout_fraction", self.holdout_fraction, 0.05, 0.7)
        if not isinstance(self.blocks, int) or self.blocks < 3:
            raise ParameterError("blocks", "an integer >= 3", self.blocks)
        if not isinstance(self.max_effects, int) or not 0 <= self.max_effects <= len(FAMILIES):
            raise ParameterError(
                "max_effects", f"an integer in [0, {len(FAMILIES)}]", self.max_effects
            )
        unknown = [f for f in self.families if f not in FAMILIES]
        if unknown:
            raise ParameterError("families", f"names among {', '.join(FAMILIES)}", unknown[0])


@dataclass(frozen=True)
class Effect:
    """A candidate effect with its shape parameters fixed (coefficients are fitted)."""

    name: str
    shape: dict[str, float]
    columns: tuple[str, ...]


@dataclass(frozen=True)
class Signals:
    """Full-rate signals on the samples kept by the differentiation (ends dropped)."""

    t: F64
    q: F64
    qd: F64
    qdd: F64
    qddd: F64
    force: F64


@dataclass(frozen=True)
class CandidateScore:
    """One candidate at the round it was last scored."""

    name: str
    params: dict[str, float]
    rms_before: float
    rms_after: float
    score: float
    t_stat: float
    selected: bool
    note: str = ""
    cv_effect: float = math.nan  # mean per-fold share of the floor removed on the support
    p_value: float = math.nan  # one-sided across folds (before Holm)
    folds_used: int = 0  # folds with enough support
    support_fraction: float = math.nan  # mean share of validation rows on the support
    passed: bool = False  # passed Holm and the minimum effect size at its last round


@dataclass(frozen=True, eq=False)
class ResidualResult:
    """Outcome of :func:`analyse_rigid`.

    ``rms_*`` and ``relerr_*`` are on the held-out decimated samples; ``f_hat_*`` are the
    model efforts at every input sample (full rate).
    """

    names_before: tuple[str, ...]
    theta_before: F64
    names_after: tuple[str, ...]
    theta_after: F64
    effects: tuple[Effect, ...]
    candidates: tuple[CandidateScore, ...]
    holdout_start: float
    holdout_stop: float
    rms_before: float
    rms_after: float
    relerr_before: float
    relerr_after: float
    unexplained: tuple[dict[str, float | str], ...]
    f_hat_before: F64
    f_hat_after: F64
    t_dec: F64
    residual_before_dec: F64
    residual_after_dec: F64
    q_dec: F64
    qd_dec: F64
    indistinguishable: tuple[dict[str, object], ...] = ()
    selection: SelectionParams = field(default_factory=SelectionParams)


# ----------------------------------------------------------------------------- columns


def effect_columns(effect: Effect, sig: Signals) -> F64:
    """Regressor columns of ``effect`` over the samples of ``sig`` (shape ``(n, k)``)."""
    if effect.name in _families.FAMILIES:
        return _families.FAMILIES[effect.name].columns(effect.shape, sig)
    v = sig.qd
    n = len(v)
    name = effect.name
    if name == "offset":
        return np.ones((n, 1))
    if name == "inertia":
        return sig.qdd[:, None].copy()
    if name == "viscous":
        return v[:, None].copy()
    if name == "coulomb_asymmetry":
        return np.column_stack([(v > 0).astype(np.float64), np.abs(v)])
    if name == "stribeck":
        vs = effect.shape["v_s"]
        return (np.sign(v) * np.exp(-((np.abs(v) / vs) ** 2)))[:, None]
    if name == "position_periodic":
        w = 2.0 * np.pi * sig.q / effect.shape["period"]
        return np.column_stack([np.cos(w), np.sin(w), np.cos(2 * w), np.sin(2 * w)])
    if name == "harmonic":
        w = 2.0 * np.pi * effect.shape["frequency"] * sig.t
        return np.column_stack([np.cos(w), np.sin(w)])
    if name == "delay":
        return _delay_column(effect.shape, sig)[:, None]
    if name == "drift":
        t0, span = effect.shape["t0"], effect.shape["span"]
        return ((sig.t - t0) / span)[:, None]
    raise ParameterError("effect", f"one of {', '.join(FAMILIES)}", name)


def _columns_names(name: str) -> tuple[str, ...]:
    return {
        "offset": ("offset",),
        "inertia": ("inertia",),
        "viscous": ("viscous",),
        "coulomb_asymmetry": ("dir_pos", "abs_v"),
        "stribeck": ("F_s",),
        "position_periodic": ("c1", "s1", "c2", "s2"),
        "harmonic": ("c", "s"),
        "delay": ("gain",),
        "drift": ("slope",),
    }[name]


# ------------------------------------------------------------------------ shape search


def _finite(shape: dict[str, float]) -> bool:
    return all(math.isfinite(v) for v in shape.values())


def _project_rss(cols: F64, r: F64) -> float:
    # normal equations: a few columns, well scaled (sin/cos, unit exponentials, ones)
    g = cols.T @ cols
    b = cols.T @ r
    if np.linalg.cond(g) < 1e10:
        coef = np.linalg.solve(g, b)
    else:  # near-singular (e.g. a vanishing Stribeck column): the robust solver
        coef, *_ = np.linalg.lstsq(cols, r, rcond=None)
        return float(np.sum((r - cols @ coef) ** 2))
    return float(r @ r - b @ coef)


def _search_period(q: F64, r: F64, dq_min: float) -> tuple[float, float]:
    """Period in position of the strongest periodic component of ``r`` (grid + refine)."""
    span = float(np.ptp(q))
    lo = max(4.0 * dq_min, span * 1e-4, 1e-12)
    hi = span / 2.0
    if not hi > lo:
        return math.nan, math.inf
    grid = np.geomspace(lo, hi, 160)

    def rss(p: float) -> float:
        w = 2.0 * np.pi * q / p
        return _project_rss(np.column_stack([np.cos(w), np.sin(w)]), r)

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


def _nominal_effort(shape: dict[str, float], sig: Signals) -> F64:
    return np.asarray(
        rigid_regressor(sig.qd, sig.qdd)
        @ np.array([shape["M"], shape["Fv"], shape["Fc"], shape["offset"]]),
        dtype=np.float64,
    )


def _delay_column(shape: dict[str, float], sig: Signals) -> F64:
    """``P(t - d) - P(t)`` with ``P`` the nominal effort (linear interpolation in time)."""
    p = _nominal_effort(shape, sig)
    # the first d seconds have no past: P is held at its first value there
    return np.asarray(np.interp(sig.t - shape["delay_s"], sig.t, p) - p, dtype=np.float64)


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


def find_shape(
    name: str,
    sig: Signals,
    residual: F64,
    mask: NDArray[np.bool_],
    nominal: F64 | None = None,
    max_samples: int = _SEARCH_SAMPLES,
    decimation: int = 1,
) -> Effect:
    """Fix the shape parameters of family ``name`` from the residual on ``mask`` samples
    (searched on at most ``max_samples`` of them, evenly spaced).

    ``nominal`` (M, Fv, Fc, offset of the current model) is needed by ``delay``;
    ``decimation`` (of the regressor) bounds the harmonic's frequency.
    """
    idx = np.flatnonzero(mask)
    stride = max(1, int(math.ceil(len(idx) / max_samples)))
    idx = idx[::stride]
    r = residual[idx]
    if name in _families.FAMILIES:
        fam = _families.FAMILIES[name]
        shape_ = fam.search(sig, r, idx, nominal)
        return Effect(name, shape_, fam.column_names(shape_) if _finite(shape_) else ())
    shape: dict[str, float] = {}
    if name == "stribeck":
        vmax = float(np.max(np.abs(sig.qd[idx])))
        sub = Signals(
            sig.t[idx], sig.q[idx], sig.qd[idx], sig.qdd[idx], sig.qddd[idx], sig.force[idx]
        )

        def rss_vs(vs: float) -> float:
            cols = effect_columns(Effect("stribeck", {"v_s": float(vs)}, ()), sub)
            return _project_rss(np.column_stack([cols, np.ones(len(idx))]), r)

        grid = np.geomspace(max(vmax * 1e-3, 1e-12), vmax * 0.5, 40)
        shape = {"v_s": refine_grid(rss_vs, grid, log=True)}
    elif name == "position_periodic":
        dq = float(np.median(np.abs(np.diff(sig.q)))) if len(sig.q) > 1 else 0.0
        period, _ = _search_period(sig.q[idx], r - r.mean(), dq)
        shape = {"period": period}
    elif name == "harmonic":
        tt, rr = gap_filled(sig.t, residual, mask)
        # below the anti-alias filter of the decimation (the regressor is decimated:
        # a column above it is filtered away and its coefficient is meaningless)
        fs = 1.0 / float(np.median(np.diff(sig.t)))
        freq, _ = search_frequency(tt, rr, f_max=0.9 * 0.4 * fs / decimation)
        if math.isfinite(freq) and freq > 0:
            # refine within +-1 bin of the padded FFT by least squares on the residual
            df = 1.0 / (4.0 * max(float(tt[-1] - tt[0]), 1e-12))
            ts_, rs_ = sig.t[idx], r - r.mean()

            def rss(fr: float) -> float:
                w = 2.0 * np.pi * fr * ts_
                return _project_rss(np.column_stack([np.cos(w), np.sin(w)]), rs_)

            fine = np.linspace(max(freq - df, df * 1e-3), freq + df, 41)
            freq = float(fine[int(np.argmin([rss(fr) for fr in fine]))])
        shape = {"frequency": freq}
    elif name == "delay":
        if nominal is None:
            raise ParameterError("nominal", "the nominal parameters (M, Fv, Fc, offset)", None)
        base = dict(zip(("M", "Fv", "Fc", "offset"), map(float, nominal[:4])))
        ts = float(np.median(np.diff(sig.t)))
        span = float(sig.t[-1] - sig.t[0])
        # lags from one sample to 5 % of the record (at most 0.5 s)
        grid = np.geomspace(ts, max(min(0.5, 0.05 * span), 2 * ts), 40)
        p_full = _nominal_effort(base, sig)
        t_sub = sig.t[idx]

        def rss_d(d: float) -> float:
            # the column of _delay_column, evaluated on the search samples only
            col = np.interp(t_sub - d, sig.t, p_full) - p_full[idx]
            return _project_rss(np.column_stack([col, np.ones(len(idx))]), r)

        shape = {**base, "delay_s": refine_grid(rss_d, grid, log=True)}
    elif name == "drift":
        tt = sig.t[np.flatnonzero(mask)]
        shape = {"t0": float(tt[0]), "span": float(max(tt[-1] - tt[0], 1e-12))}
    return Effect(name, shape, _columns_names(name))


# ---------------------------------------------------------------------------- fitting


@dataclass(frozen=True, eq=False)
class _Design:
    """Decimated regressor, force and the full-rate columns of one model structure."""

    names: tuple[str, ...]
    x_dec: F64
    x_full: F64


def _build(
    sig: Signals,
    effects: tuple[Effect, ...],
    p: IdimParams,
    cache: dict[tuple[str, tuple[tuple[str, float], ...]], tuple[F64, F64]] | None = None,
) -> _Design:
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
    return _Design(tuple(names), np.hstack(dec), np.hstack(full))


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


def _fit(design: _Design, y_dec: F64, fit: NDArray[np.bool_]) -> tuple[F64, NDArray[np.bool_]]:
    """Least squares on the fitting samples; returns theta (0 for dropped columns), keep."""
    keep = _independent(design.x_dec, len(RIGID_NAMES), fit)
    theta = np.zeros(design.x_dec.shape[1])
    sol, *_ = np.linalg.lstsq(design.x_dec[fit][:, keep], y_dec[fit], rcond=None)
    theta[keep] = sol
    return theta, keep


def block_t(d: F64, blocks: int) -> float:
    """t statistic of the mean of ``d`` over ``blocks`` contiguous blocks (the blocks'
    means as the samples: serial correlation inside a block does not inflate it)."""
    means = np.array([float(np.mean(b)) for b in np.array_split(d, blocks) if len(b)])
    sd = float(np.std(means, ddof=1))
    if sd == 0.0:
        return math.inf if float(np.mean(means)) > 0 else 0.0
    return float(np.mean(means)) / (sd / math.sqrt(len(means)))


def _block_t(e0: F64, e1: F64, blocks: int) -> float:
    return block_t(e0 * e0 - e1 * e1, blocks)


def _effect_params(
    effect: Effect,
    design: _Design,
    theta: F64,
) -> dict[str, float]:
    out = dict(effect.shape)
    byname = dict(zip(design.names, theta))
    for cn in effect.columns:
        out[cn] = float(byname.get(f"{effect.name}.{cn}", 0.0))
    if effect.name in _families.FAMILIES:
        out.update(_families.FAMILIES[effect.name].derived(effect.shape, out))
    if effect.name == "position_periodic":
        out["amplitude_1"] = math.hypot(out["c1"], out["s1"])
        out["amplitude_2"] = math.hypot(out["c2"], out["s2"])
    if effect.name == "harmonic":
        out["amplitude"] = math.hypot(out["c"], out["s"])
    if effect.name == "coulomb_asymmetry":
        fv, fc, off = byname["Fv"], byname["Fc"], byname["offset"]
        out["Fv_pos"] = float(fv + out["abs_v"])
        out["Fv_neg"] = float(fv - out["abs_v"])
        out["Fc_pos"] = float(fc + off + out["dir_pos"])
        out["Fc_neg"] = float(fc - off)
    return out


# ----------------------------------------------------------------------- unexplained


def unexplained_structure(
    sig: Signals, residual: F64, *, prominence: float = 6.0, min_ratio: float = 0.15
) -> list[dict[str, float | str]]:
    """The largest periodic structure left in ``residual``, in time and in position.

    A peak is reported when its amplitude is at least ``prominence`` times the median
    amplitude of its spectrum and at least ``min_ratio`` times the residual's rms.
    """
    out: list[dict[str, float | str]] = []
    level = rms(residual)
    if level == 0.0:
        return out
    freq, amp = search_frequency(sig.t, residual)
    n = len(residual)
    win = np.hanning(n)
    spec = np.abs(np.fft.rfft((residual - residual.mean()) * win)) * 2.0 / win.sum()
    med = float(np.median(spec[1:])) if len(spec) > 1 else 0.0
    if math.isfinite(freq) and amp >= prominence * med and amp >= min_ratio * level:
        out.append(
            {"domain": "time", "frequency_hz": freq, "amplitude": amp, "ratio_to_rms": amp / level}
        )
    stride = max(1, int(math.ceil(n / _SEARCH_SAMPLES)))
    q, r = sig.q[::stride], residual[::stride] - residual.mean()
    dq = float(np.median(np.abs(np.diff(sig.q)))) if n > 1 else 0.0
    period, _ = _search_period(q, r, dq)
    if math.isfinite(period):
        w = 2.0 * np.pi * q / period
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


# ----------------------------------------------------------------------------- driver


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


def _full_rate(values: F64, n: int) -> F64:
    """Extend a series over samples 1..n-2 to 0..n-1 (ends repeat their neighbour)."""
    out = np.empty(n)
    out[1:-1] = values
    out[0], out[-1] = values[0], values[-1]
    return out


def analyse_rigid(
    q: ArrayLike,
    force: ArrayLike,
    t: ArrayLike,
    sample_time: float,
    params: ResidualParams = ResidualParams(),
    *,
    progress: Callable[[str], None] | None = None,
) -> ResidualResult:
    """Fit the rigid nominal model, search the effect library greedily, score held out.

    Parameters
    ----------
    q, force, t : array_like
        Position, effort and time, uniformly sampled, same length.
    sample_time : float
        Sampling interval [s].
    params : ResidualParams
        Settings.
    progress : callable, optional
        Called with a short message at each stage.

    Raises
    ------
    ParameterError
        If the record is too short for the held-out split.
    """
    qa = np.asarray(q, dtype=np.float64)
    n = len(qa)
    p = params.idim
    min_dec = 40 * params.blocks
    if n < 3 + p.decimation * min_dec:
        raise ParameterError(
            "samples",
            f"at least {3 + p.decimation * min_dec} samples for the held-out split "
            f"({min_dec} decimated samples)",
            n,
        )
    sig = signals(qa, force, t, sample_time, p)
    m = len(sig.t)
    di = decimated_index(m, p)
    y_dec = decimate(sig.force, p)
    t_dec = sig.t[di]
    split = int(round((1.0 - params.holdout_fraction) * len(t_dec)))
    fit = np.zeros(len(t_dec), dtype=bool)
    fit[:split] = True
    hold = ~fit
    if hold.sum() < 4 * params.blocks or fit.sum() < 20:
        raise ParameterError(
            "samples", "enough decimated samples on both sides of the split", int(hold.sum())
        )
    # full-rate mask of the fitting part (for shape searches)
    fit_full = sig.t < t_dec[split]

    def say(msg: str) -> None:
        if progress is not None:
            progress(msg)

    say("nominal fit")
    cache: dict[tuple[str, tuple[tuple[str, float], ...]], tuple[F64, F64]] = {}
    design0 = _build(sig, (), p, cache)
    theta0, _ = _fit(design0, y_dec, fit)
    e0 = y_dec[hold] - design0.x_dec[hold] @ theta0
    selected: tuple[Effect, ...] = ()
    design, theta, e_cur = design0, theta0, e0
    scores: dict[str, CandidateScore] = {}
    ambiguous: list[dict[str, object]] = []
    sp = params.selection
    folds = make_folds(len(t_dec), split, sp.folds, _guard_rows(sample_time, p))
    # full-rate sample -> its decimated row (for the shape searches inside a fold)
    row_of = np.clip(np.searchsorted(t_dec, sig.t), 0, len(t_dec) - 1)
    # the candidate list: params.families (default FAMILIES, the one marked place above)
    offered = list(params.families)
    while len(selected) < params.max_effects:
        say(f"cross-validation round {len(selected) + 1}")
        resid_full = sig.force - design.x_full @ theta
        before = [_fit(design, y_dec, fd.train)[0] for fd in folds]
        trials: list[_RigidTrial] = []
        for name in offered:
            if any(e.name == name for e in selected):
                continue
            say(f"candidate {name}")
            eff = find_shape(name, sig, resid_full, fit_full, theta[:4], decimation=p.decimation)
            if any(not math.isfinite(v) for v in eff.shape.values()):
                scores[name] = CandidateScore(
                    name, eff.shape, rms(e_cur), rms(e_cur), 0.0, 0.0, False, "no shape found"
                )
                continue
            d = _build(sig, (*selected, eff), p, cache)
            th, keep = _fit(d, y_dec, fit)
            e1 = y_dec[hold] - d.x_dec[hold] @ th
            added = int(keep[len(design.names) :].sum())
            gain = 1.0 - float(np.mean(e1**2)) / max(float(np.mean(e_cur**2)), 1e-300)
            pars = _effect_params(eff, d, th)
            if not added:
                scores[name] = CandidateScore(
                    name, pars, rms(e_cur), rms(e1), gain, 0.0, False,
                    "spanned by the current model (nothing new)",
                )  # fmt: skip
                continue
            nc = len(design.names)
            ver = _rigid_oof(design.x_dec, d.x_dec[:, nc:], y_dec, folds, before, sp)
            note = ""
            if name in _SHAPED_RIGID:
                if (
                    math.isfinite(ver.mean_effect)
                    and ver.mean_effect >= 0.5 * sp.min_effect
                    and ver.p_value < 0.5
                ):
                    cand_k = []
                    for fd, th_k in zip(folds, before):
                        r_k = sig.force - design.x_full @ th_k
                        tr_full = fd.train[row_of]
                        e_k = find_shape(
                            name, sig, r_k, tr_full, th_k[:4], _FOLD_SEARCH, p.decimation
                        )
                        if any(not math.isfinite(v) for v in e_k.shape.values()):
                            e_k = eff
                        cand_k.append(decimate(effect_columns(e_k, sig), p))
                    ver = _rigid_oof(design.x_dec, cand_k, y_dec, folds, before, sp)
                else:
                    note = "screened out (shape of the whole fitting part; not re-searched)"
            term = d.x_dec[fit][:, nc:] @ th[nc:]
            trials.append(_RigidTrial(name, eff, d, th, e1, ver, term, len(eff.columns)))
            scores[name] = CandidateScore(
                name, pars, rms(e_cur), rms(e1), gain, ver.t_stat, False, note,
                cv_effect=ver.mean_effect, p_value=ver.p_value, folds_used=ver.folds_used,
                support_fraction=ver.support_fraction,
            )  # fmt: skip
        if not trials:
            break
        passes = holm([tr.verdict.p_value for tr in trials], sp.alpha)
        accepted = [
            tr for tr, ok in zip(trials, passes) if ok and tr.verdict.mean_effect >= sp.min_effect
        ]
        for tr in trials:
            scores[tr.name] = replace(scores[tr.name], passed=tr in accepted)
        if not accepted:
            break
        best = max(accepted, key=lambda tr: tr.verdict.total_reduction)
        same = [
            tr
            for tr in accepted
            if tr is best
            or (
                correlation(tr.term, best.term) >= sp.same_signal
                and tr.verdict.total_reduction >= (1.0 - sp.tie) * best.verdict.total_reduction
            )
        ]
        choice = min(same, key=lambda tr: (tr.ncols, -tr.verdict.total_reduction))
        if len(same) > 1:
            ambiguous.append(ambiguity([tr.name for tr in same], choice.name, sp.same_signal))
        selected = (*selected, choice.effect)
        design, theta, e_cur = choice.design, choice.theta, choice.e_hold
        scores[choice.name] = replace(scores[choice.name], selected=True)
    # final joint parameters of the selected effects
    final_scores = []
    for sc in scores.values():
        if sc.selected:
            eff = next(e for e in selected if e.name == sc.name)
            sc = replace(sc, params=_effect_params(eff, design, theta))
        final_scores.append(sc)
    say("unexplained structure")
    resid_after_full = sig.force - design.x_full @ theta
    hold_full = ~fit_full
    unexpl = unexplained_structure(_subset(sig, hold_full), resid_after_full[hold_full])
    y_h = y_dec[hold]
    norm_y = max(float(np.linalg.norm(y_h)), 1e-300)
    return ResidualResult(
        names_before=design0.names,
        theta_before=theta0,
        names_after=design.names,
        theta_after=theta,
        effects=selected,
        candidates=tuple(final_scores),
        holdout_start=float(t_dec[split]),
        holdout_stop=float(t_dec[-1]),
        rms_before=rms(e0),
        rms_after=rms(e_cur),
        relerr_before=100.0 * float(np.linalg.norm(e0)) / norm_y,
        relerr_after=100.0 * float(np.linalg.norm(e_cur)) / norm_y,
        unexplained=tuple(unexpl),
        f_hat_before=_full_rate(design0.x_full @ theta0, n),
        f_hat_after=_full_rate(design.x_full @ theta, n),
        t_dec=t_dec,
        residual_before_dec=y_dec - design0.x_dec @ theta0,
        residual_after_dec=y_dec - design.x_dec @ theta,
        q_dec=sig.q[di],
        qd_dec=sig.qd[di],
        indistinguishable=tuple(ambiguous),
        selection=sp,
    )


#: families with shape parameters (searched again inside each training fold)
_SHAPED_RIGID = frozenset({"stribeck", "position_periodic", "harmonic", "delay"})
#: samples of a shape search inside a fold
_FOLD_SEARCH = 20_000


@dataclass(frozen=True, eq=False)
class _RigidTrial:
    name: str
    effect: Effect
    design: _Design
    theta: F64
    e_hold: F64
    verdict: Verdict
    term: F64
    ncols: int


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
) -> Verdict:
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
    return verdict(OutOfFold(sq0, sq1, supp), sp.blocks, test=sp.test)


def _subset(sig: Signals, mask: NDArray[np.bool_]) -> Signals:
    return Signals(
        sig.t[mask], sig.q[mask], sig.qd[mask], sig.qdd[mask], sig.qddd[mask], sig.force[mask]
    )


def apply_model(
    result: ResidualResult,
    q: ArrayLike,
    force: ArrayLike,
    t: ArrayLike,
    sample_time: float,
    p: IdimParams | None = None,
) -> dict[str, float]:
    """Held-out numbers of ``result``'s models (before/after) on a second record.

    Returns ``rms_before``, ``rms_after``, ``relerr_before``, ``relerr_after`` over all
    decimated samples of the record (none of it was fitted).
    """
    p = IdimParams() if p is None else p
    sig = signals(q, force, t, sample_time, p)
    y = decimate(sig.force, p)
    d0 = _build(sig, (), p)
    d1 = _build(sig, result.effects, p)
    e0 = y - d0.x_dec @ result.theta_before
    e1 = y - d1.x_dec @ result.theta_after
    ny = max(float(np.linalg.norm(y)), 1e-300)
    return {
        "rms_before": rms(e0),
        "rms_after": rms(e1),
        "relerr_before": 100.0 * float(np.linalg.norm(e0)) / ny,
        "relerr_after": 100.0 * float(np.linalg.norm(e1)) / ny,
    }
