r"""Live identification of a rigid feed axis, and its process force (issue 30 item 3).

The axis is the EMPS benchmark's inverse dynamic model (:mod:`estimators.idim`),

.. math:: \tau = M\ddot q + F_v\dot q + F_c\,\mathrm{sign}(\dot q) + \tau_{off}
          + \sum_j \theta_j\,\phi_j(q, \dot q, \ddot q, \dddot q, t),

with the effects :math:`\phi_j` the offline residual loop selected for the axis (their
shapes fixed by its report, their coefficients identified here with :math:`M, F_v,
F_c`). Nothing is assumed known: no nominal, no prior. Each step is a choice:

1. **Parallel filtering, causal** (Gautier's IDIM practice). Every column of the model
   is computed from the raw kinematics (velocity, acceleration and jerk as central
   differences of the encoder's position, referred to the previous sample: a quantum of
   0.05 um at 1 kHz is 2.5e-5 m/s of velocity, so the sign of the velocity is right
   everywhere but within that of a reversal), then every column and the effort go
   through the same low-pass :math:`P(s) = (\omega_c/(s+\omega_c))^4`. The model's
   equation then holds exactly between the filtered signals, the nonlinear columns
   included (taking the sign of a filtered velocity instead is exact only for the linear
   part; on the tests' simulated axis both come within 0.1 %, but the exact form costs
   nothing more). The cut-off is designed from the rate
   (:func:`rigid_design`): the benchmark's 100 Hz at 1 kHz and above, a tenth of the rate
   below; the rows are decimated to about 100 per second.
2. **Below 100 Hz** an acceleration lasts one or two samples and a position exported to
   a few digits does not difference: the CNC's own velocity and acceleration are used
   (``qd``, ``qdd`` given), unfiltered; without an acceleration the mass is not
   identified, and says why.
3. **Gated on excitation.** A row enters only while the axis moves: :math:`|\dot q|`
   above ``moving_rel`` of the fastest speed seen (standstill is stiction, which the model
   does not describe), and only where the caller allows learning (``learn``: e.g. the
   tool in the air). Each parameter is *excited* when its 95 % half-width is at most
   ``excited_rel`` of its value (the offset: of :math:`F_c`).
4. **Forgetting**: exponentially weighted least squares over the rows, the weight of a
   row :math:`e^{-\Delta/T}` with :math:`\Delta` the *moving* time since it (the clock
   stops while the axis stands), :math:`T` = ``memory_s`` (10 s: the last 10 s of motion
   weigh more than :math:`e^{-1}`; the information matrix is the recursive
   :math:`G \leftarrow \lambda^m G + \sum \lambda^{m-1-i} x_i x_i^T`). Not a growing
   window: a friction that warms up or a table that is loaded is followed within a few
   memories.
5. **Intervals**: Newey-West (Bartlett kernel, Andrews' bandwidth) over the rows kept
   (``keep_memories`` memories, the weights beyond are below :math:`e^{-5}`), recomputed
   every ``hac_every_s`` of moving time (:mod:`estimators.hac`). The plain least-squares
   covariance is kept beside it (``cov_plain``) to show how much narrower it is.
6. **Identifiability.** A column the others span on the rows (a report's ``dir_pos``
   beside the sign and the offset; an effect's column the data cannot separate) is left
   out, in column order, the base first (ordered Cholesky with a relative pivot
   tolerance); its coefficient is reported NaN.
7. **The process force** :math:`F = P[\tau] - \phi^T\hat\theta` with the estimate held
   before the block (a priori: the process force is never fitted away by the sample it
   is in), and its standard uncertainty :math:`\sqrt{\phi^T C\phi + s^2}`: the model's
   uncertainty and the rms residual of the window (the effort no model explains); at
   standstill with the static friction's spread beside them, :math:`F_c/\sqrt 3` (a
   level anywhere within :math:`\pm F_c`). **At standstill the force's Coulomb column
   is 0**, not the sign of the velocity (a column of its own, filtered alike; the rows
   learnt from keep the sign), below ``static_rel`` (0.1 %) of the fastest speed seen:
   there friction is static, whatever balances the other forces within
   :math:`\pm F_c`, and the sign of a quantised encoder's difference is its dither
   and the position loop's creep after a stop (on the machining centre 1e-5 to 1e-4
   m/s, 0.002-0.02 % of its rapid; its slowest feed is 2.7 %). With the sign, the
   process force of an axis at rest (most of a machining centre's time: the others
   cut) took a random :math:`\pm F_c`: on the centre's 500 Hz trace 92-99 % of the
   force error's square (X 89 N rms of a 106 N force; 42 N without it,
   ``docs/machining-centre.md``). An axis passing slowly through a reversal has its
   friction developed: at 2 % (the gate of 3) the EMPS record's force residual grew
   from 4.15 % to 5.33 %; at 0.1 % it is 4.19 %.

Per-sample work is one numba kernel (filters and differences); the rest is per block on
the decimated rows.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
from numba import njit
from numpy.typing import NDArray
from scipy import stats

from common.arrays import F64
from estimators.errors import ParameterError, require_positive
from estimators.filters import df2t_step, lowpass
from estimators.hac import andrews_bandwidth, effective_rows, hac_covariance
from estimators.residual.families import FAMILIES
from estimators.residual.rate import LOW_RATE_HZ, low_rate_reasons

#: the base parameters, in column order
BASE: tuple[str, ...] = ("M", "Fv", "Fc", "offset")
#: the rows per second of the regression (as the benchmark's IDIM: 1 kHz decimated by 10)
ROW_RATE_HZ = 100.0
#: the benchmark's position filter [Hz], kept at and above 1 kHz
FILTER_HZ = 100.0
#: the forgetting's memory holds at least this many rows: 10 s at 100 rows per second,
#: 100 s of motion at 10 Hz (where each row is a coarser snapshot of a move)
MEMORY_ROWS = 1000
MEMORY_S = 10.0
#: families whose columns need a record's past and future: not causal, not live
NOT_LIVE: dict[str, str] = {
    "delay": "its column is the effort shifted in time around the sample (needs the future)",
    "drive_delay": "its column is the effort a little later than the sample (needs the future)",
    "drift": "a change over the record's time; live, the forgetting follows it",
    "load": "needs the rows where a process load acts (not known live)",
}


@dataclass(frozen=True)
class LiveEffect:
    """One effect of a residual report: its family and its shape (fixed)."""

    name: str
    shape: tuple[tuple[str, float], ...]

    @classmethod
    def of(cls, name: str, shape: Mapping[str, float]) -> LiveEffect:
        return cls(name, tuple((k, float(v)) for k, v in shape.items()))

    @property
    def shape_dict(self) -> dict[str, float]:
        return dict(self.shape)

    def column_names(self) -> tuple[str, ...]:
        return tuple(f"{self.name}.{c}" for c in FAMILIES[self.name].column_names(self.shape_dict))


@dataclass(frozen=True)
class RigidIdParams:
    """Design of the live rigid identifier (module docstring; :func:`rigid_design` makes
    it from the rate and the signals the axis has)."""

    sample_time: float
    filter_hz: float = FILTER_HZ  # the parallel low-pass; nan: none (below 100 Hz)
    filter_order: int = 4
    decimation: int = 10
    velocity: str = "differenced"  # or "given": the CNC's velocity
    acceleration: str = "differenced"  # "given": the CNC's; "none": M not identified
    memory_s: float = 10.0
    keep_memories: float = 5.0
    hac_every_s: float = 1.0
    moving_rel: float = 0.02
    static_rel: float = 1e-3  # standstill for the process force's friction (docstring, 7)
    settle_s: float = 0.1  # after a (re)start, the filters' transient is not learnt from
    min_rows: int = 40
    level: float = 0.95
    excited_rel: float = 0.10
    effects: tuple[LiveEffect, ...] = ()

    def __post_init__(self) -> None:
        ts = require_positive("sample_time", self.sample_time)
        if not math.isnan(self.filter_hz) and not 0 < self.filter_hz < 0.5 / ts:
            raise ParameterError(
                "filter_hz", f"a cut-off in (0, {0.5 / ts:g}) Hz or nan", self.filter_hz
            )
        if int(self.decimation) != self.decimation or self.decimation < 1:
            raise ParameterError("decimation", "an integer >= 1", self.decimation)
        if self.velocity not in ("differenced", "given"):
            raise ParameterError("velocity", "'differenced' or 'given'", self.velocity)
        if self.acceleration not in ("differenced", "given", "none"):
            raise ParameterError(
                "acceleration", "'differenced', 'given' or 'none'", self.acceleration
            )
        for name in (
            "memory_s",
            "keep_memories",
            "hac_every_s",
            "moving_rel",
            "static_rel",
            "excited_rel",
        ):
            require_positive(name, getattr(self, name))
        if not 0.5 < self.level < 1:
            raise ParameterError("level", "a coverage in (0.5, 1)", self.level)
        for e in self.effects:
            if e.name not in FAMILIES or e.name in NOT_LIVE:
                raise ParameterError(
                    "effects", f"families of the live model ({live_families()})", e.name
                )

    @property
    def row_time(self) -> float:
        """Seconds between two regression rows."""
        return self.sample_time * self.decimation

    @property
    def has_mass(self) -> bool:
        return self.acceleration != "none"

    def names(self) -> tuple[str, ...]:
        """The coefficient names, in column order."""
        base = BASE if self.has_mass else BASE[1:]
        return base + tuple(n for e in self.effects for n in e.column_names())


def live_families() -> str:
    return ", ".join(n for n in FAMILIES if n not in NOT_LIVE)


def rigid_design(
    sample_time: float,
    *,
    velocity_given: bool = False,
    acceleration_given: bool = False,
    effects: Sequence[LiveEffect] = (),
    memory_s: float | None = None,
) -> tuple[RigidIdParams, dict[str, str]]:
    """The identifier for an axis sampled every ``sample_time`` s, and what cannot run.

    At and above 100 Hz: the parallel filter at min(100 Hz, a tenth of the rate), rows
    decimated to about 100 per second, velocity and acceleration differenced. Below: no
    filter, every row, the CNC's velocity (``velocity_given``; else differenced) and
    acceleration (``acceleration_given``; else the mass is not identified). Effects a
    live model cannot hold or this rate cannot show are left out. The memory (default):
    10 s of motion, or :data:`MEMORY_ROWS` rows where that is longer.

    Returns
    -------
    params, reasons
        ``reasons`` maps what does not run (``M``, an effect's name) to why.
    """
    fs = 1.0 / require_positive("sample_time", sample_time)
    reasons: dict[str, str] = {}
    low = fs < LOW_RATE_HZ
    low_reasons = low_rate_reasons(fs) if low else {}
    keep = []
    for e in effects:
        why = NOT_LIVE.get(e.name) or low_reasons.get(e.name)
        if e.name not in FAMILIES:
            why = f"not a family of the rigid model ({live_families()})"
        if why:
            reasons[e.name] = why
        else:
            keep.append(e)
    acc = "differenced"
    if low:
        acc = "given" if acceleration_given else "none"
        if not acceleration_given:
            reasons["M"] = (
                f"at {fs:g} Hz an acceleration phase lasts one or two samples and cannot be "
                "had by differencing: the mass needs the CNC's acceleration (qdd_m or qdd_cmd)"
            )
    decimation = 1 if low else max(1, int(round(fs / ROW_RATE_HZ)))
    if memory_s is None:
        memory_s = max(MEMORY_S, MEMORY_ROWS * decimation / fs)
    params = RigidIdParams(
        sample_time=sample_time,
        filter_hz=math.nan if low else min(FILTER_HZ, 0.1 * fs),
        decimation=decimation,
        velocity="given" if low and velocity_given else "differenced",
        acceleration=acc,
        memory_s=memory_s,
        effects=tuple(keep),
    )
    return params, reasons


# --------------------------------------------------------------------------- state


# Index of each entry of RigidIdState.prev: the raw position one and two samples back,
# the raw acceleration one sample back, the effort, the given velocity and acceleration
# one sample back, samples seen
PV_Q1, PV_Q2, PV_A1, PV_T1, PV_V1, PV_GA1, PV_SEEN = 0, 1, 2, 3, 4, 5, 6
PV_SIZE = 7
# Index of each entry of RigidIdState.stats
ST_VMAX, ST_ROWS, ST_REVERSALS, ST_SIGN, ST_MOVING_T, ST_SINCE_HAC = 0, 1, 2, 3, 4, 5
ST_BANDWIDTH, ST_S2, ST_NEFF, ST_SAMPLES, ST_START_T, ST_PHASE = 6, 7, 8, 9, 10, 11
ST_SIZE = 12


@dataclass
class RigidIdState:
    """Explicit state of the live rigid identifier."""

    z: F64  # (p + 3, order) filter states: the p columns, the effort, the velocity, the
    # force's Coulomb column (0 at standstill)
    prev: F64  # PV_*
    G: F64  # (p, p) exponentially weighted information matrix
    b: F64  # (p,) its right-hand side
    rows: F64  # (m, 2 + p) kept rows: t, y, x (oldest first), as of the last refresh
    pending: F64  # (k, 2 + p) rows since the last refresh (merged into rows there)
    theta: F64  # (p,) the estimate (nan: not identifiable yet)
    cov: F64  # (p, p) Newey-West covariance
    cov_plain: F64  # (p, p) plain least-squares covariance (for comparison)
    active: F64  # (p,) 1 where the column is identifiable
    stats: F64  # ST_*


@dataclass
class RigidIdRecord:
    """One block's outputs: per sample the process force and its uncertainty; the
    estimate after the block with its interval and excitation; diagnostics."""

    t: F64  # time each sample's output refers to (one sample back)
    force: F64  # process force P[tau] - phi theta (a priori)
    force_sd: F64  # its standard uncertainty
    effort: F64  # P[tau]: the filtered effort the force is taken from
    theta: F64  # (p,)
    lower: F64  # (p,) 95 % interval (Newey-West)
    upper: F64
    half_plain: F64  # (p,) 95 % half-width of plain least squares
    excited: NDArray[np.bool_]  # (p,) the base parameters' flags (effects: False)
    rows: int  # rows learnt from so far
    reversals: int
    moving_time: float  # s of motion learnt from
    bandwidth: int  # Newey-West bandwidth (rows)
    residual_rms: float
    #: the friction level of each direction (Fc_pos, Fc_neg): value and 95 % half-width
    directions: dict[str, tuple[float, float]] = field(default_factory=dict)
    #: the two levels differ: the 95 % interval of their difference excludes 0 (on a
    #: rigid model that is an offset: gravity, an amplifier's offset, or friction that
    #: differs by direction, which moving rows cannot tell apart)
    direction_differs: bool = False


class KinematicsIn(NamedTuple):
    """One block's samples as :func:`_kinematics_kernel` reads them (read only)."""

    q: F64  # position
    tau: F64  # effort
    vg: F64  # the given velocity (read with ``given_v``)
    ag: F64  # the given acceleration (read with ``given_a``)
    given_v: bool  # velocity from the feed, else central differences of q
    given_a: bool  # acceleration from the feed, else central differences of q
    ts: float  # sample time [s]


class KinematicsOut(NamedTuple):
    """The kernel's per-sample outputs (filled in place), one sample back."""

    q: F64  # position
    v: F64  # velocity
    a: F64  # acceleration
    j: F64  # jerk
    tau: F64  # effort


@njit(cache=True)
def _kinematics_kernel(
    inp: KinematicsIn, prev: F64, out: KinematicsOut
) -> None:  # pragma: no cover
    """Per sample: the raw position, velocity, acceleration, jerk and effort, all
    referred to the previous sample (central differences); ``prev`` (PV_*) is updated
    in place."""
    q, tau, vg, ag = inp.q, inp.tau, inp.vg, inp.ag
    given_v, given_a, ts = inp.given_v, inp.given_a, inp.ts
    o_q, o_v, o_a, o_j, o_tau = out.q, out.v, out.a, out.j, out.tau
    for k in range(len(q)):
        if prev[PV_SEEN] == 0.0:
            prev[PV_Q1] = prev[PV_Q2] = q[k]
            prev[PV_T1] = tau[k]
            prev[PV_V1] = vg[k]
            prev[PV_GA1] = ag[k]
            prev[PV_A1] = 0.0
            prev[PV_SEEN] = 1.0
        # central differences at k-1: v = (q_k - q_{k-2})/2ts, a = (q_k - 2q_{k-1} + q_{k-2})/ts^2
        v = (q[k] - prev[PV_Q2]) / (2.0 * ts) if not given_v else prev[PV_V1]
        acc = (q[k] - 2.0 * prev[PV_Q1] + prev[PV_Q2]) / (ts * ts) if not given_a else prev[PV_GA1]
        # jerk: backward difference of the acceleration (half a sample late: the lag
        # column it feeds is a small correction)
        o_j[k] = (acc - prev[PV_A1]) / ts
        o_q[k] = prev[PV_Q1]
        o_v[k] = v
        o_a[k] = acc
        o_tau[k] = prev[PV_T1]
        prev[PV_A1] = acc
        prev[PV_Q2] = prev[PV_Q1]
        prev[PV_Q1] = q[k]
        prev[PV_T1] = tau[k]
        prev[PV_V1] = vg[k]
        prev[PV_GA1] = ag[k]


@njit(cache=True)
def _filter_columns(x, b, a, z, out):  # pragma: no cover
    """P applied to every column of ``x`` (n, c), one filter state per column (row of z);
    a value that is not finite enters as 0."""
    for k in range(x.shape[0]):
        for c in range(x.shape[1]):
            v = x[k, c]
            out[k, c] = df2t_step(b, a, z[c], v if np.isfinite(v) else 0.0)


@njit(cache=True)
def _front_kernel(v, acc, tau, has_mass, v_static, b, a, z, out, still):  # pragma: no cover
    """The plain design's columns (no report's effects) built and filtered sample by
    sample, as :func:`columns` and :meth:`RigidIdentifier._filtered` do them: per sample
    [acc], v, sign v, 1, the effort, v, and sign v again as the force's Coulomb column
    (0 where ``|v| <= v_static``: ``still``), each through P with its own state (row of
    ``z``); a value that is not finite enters as 0. The same operations in the same
    order: the same numbers, bit for bit."""
    c0 = 1 if has_mass else 0
    row = np.empty(out.shape[1])
    for k in range(len(v)):
        vk = v[k]
        sg = 1.0 if vk > 0.0 else (-1.0 if vk < 0.0 else (0.0 if vk == 0.0 else vk))
        if has_mass:
            row[0] = acc[k]
        row[c0] = vk
        row[c0 + 1] = sg
        row[c0 + 2] = 1.0
        row[c0 + 3] = tau[k]
        row[c0 + 4] = vk
        st = abs(vk) <= v_static
        still[k] = st
        row[c0 + 5] = 0.0 if st else sg
        for c in range(out.shape[1]):
            x = row[c]
            out[k, c] = df2t_step(b, a, z[c], x if np.isfinite(x) else 0.0)


@njit(cache=True)
def _rows_kernel(first, step, v_f, t, x, learn, vmax, moving_rel, from_t, use):  # pragma: no cover
    """The rows a block may learn from (:meth:`RigidIdentifier._learn`, the same
    comparisons): every ``step``-th sample from ``first``, the largest speed among them
    (NaN if one is NaN) kept when above ``vmax``; a row moving (``|v| > moving_rel`` of
    that), settled (``t >= from_t``), allowed (``learn``) and finite. Fills ``use``
    with the rows' indices; returns their count and the new ``vmax``."""
    mx = 0.0
    nan = False
    seen = False
    for i in range(first, len(v_f), step):
        a = abs(v_f[i])
        if np.isnan(a):
            nan = True
        elif not seen or a > mx:
            mx = a
        seen = True
    if not seen:
        return 0, vmax
    if not nan and mx > vmax:
        vmax = mx
    lim = moving_rel * vmax
    m = 0
    for i in range(first, len(v_f), step):
        if abs(v_f[i]) > lim and t[i] >= from_t and learn[i]:
            ok = True
            for c in range(x.shape[1]):
                if not np.isfinite(x[i, c]):
                    ok = False
                    break
            if ok:
                use[m] = i
                m += 1
    return m, vmax


#: lower, upper, half-width without the Newey-West correction, excited, friction by
#: direction (value, half-width), whether the directions differ (:meth:`RigidIdentifier._intervals`)
_Intervals = tuple[F64, F64, F64, NDArray[np.bool_], dict[str, tuple[float, float]], bool]


class _Rows:
    """Kinematics of some rows, as the residual families read them (:class:`Kin`)."""

    def __init__(self, t: F64, q: F64, qd: F64, qdd: F64, qddd: F64) -> None:
        self.t, self.q, self.qd, self.qdd, self.qddd = t, q, qd, qdd, qddd


def columns(params: RigidIdParams, kin: _Rows) -> F64:
    """The regressor columns of ``kin``'s rows, in :meth:`RigidIdParams.names` order."""
    v = kin.qd
    base = [v, np.sign(v), np.ones_like(v)]
    if params.has_mass:
        base.insert(0, kin.qdd)
    cols = [np.column_stack(base)]
    for e in params.effects:
        sh = e.shape_dict
        if e.name == "force_lag":
            # M jerk + Fv acc with the report's M, Fv: command = force + T d(force)/dt;
            # computed here without the offline record's edge masking (a live feed has
            # no record edge; the start is not learnt from, settle_s)
            cols.append((sh["M"] * kin.qddd + sh["Fv"] * kin.qdd)[:, None])
        else:
            cols.append(np.asarray(FAMILIES[e.name].columns(sh, kin), dtype=np.float64))
    return np.hstack(cols)


#: a column whose part the earlier columns do not explain is below this share of its own
#: square norm is left out (0.3 % in amplitude: below any record's noise). Measured: a
#: report's dir_pos beside sign and offset, 2e-8..6e-7 (its only own part is the filter's
#: memory of standstill at a start); the sign beside the offset on the tests' simulated
#: axis, 0.03
SPANNED = 1e-5


def _ordered_active(G: F64, tol: float = SPANNED) -> NDArray[np.bool_]:
    """Columns kept in order: each whose part the earlier kept ones do not explain is
    above ``tol`` of its own size (equilibrated Schur complements)."""
    p = G.shape[0]
    d = np.sqrt(np.clip(np.diag(G), 0.0, None))
    keep = np.zeros(p, dtype=np.bool_)
    if not np.any(d > 0):
        return keep
    dn = np.where(d > 0, d, 1.0)
    Gs = G / np.outer(dn, dn)
    for j in range(p):
        if d[j] <= 0:
            continue
        idx = np.flatnonzero(keep)
        r = Gs[j, j]
        if len(idx):
            A = Gs[np.ix_(idx, idx)]
            c = Gs[idx, j]
            try:
                r = r - float(c @ np.linalg.solve(A, c))
            except np.linalg.LinAlgError:
                r = 0.0
        keep[j] = r > tol
    return keep


def _solve(G: F64, b: F64, active: NDArray[np.bool_]) -> F64:
    th = np.full(len(b), math.nan)
    idx = np.flatnonzero(active)
    if len(idx):
        d = np.sqrt(np.diag(G)[idx])
        A = G[np.ix_(idx, idx)] / np.outer(d, d)
        try:
            th[idx] = np.linalg.solve(A, b[idx] / d) / d
        except np.linalg.LinAlgError:
            pass
    return th


class RigidIdentifier:
    """The live rigid identifier (module docstring)."""

    def __init__(self, params: RigidIdParams) -> None:
        self.params = params
        p = params
        self.names = p.names()
        self.p = len(self.names)
        self.filter = (
            lowpass(p.filter_hz, p.sample_time, p.filter_order)
            if not math.isnan(p.filter_hz)
            else None
        )
        self.lam = math.exp(-p.row_time / p.memory_s)  # forgetting per row
        self._keep = int(math.ceil(p.keep_memories * p.memory_s / p.row_time))
        self._z = float(stats.norm.ppf(0.5 + 0.5 * p.level))
        self._fc = self.names.index("Fc")
        #: the last intervals computed and what they were computed from (:meth:`_intervals`)
        self._last_intervals: tuple[tuple[object, ...], _Intervals] | None = None

    def initial_state(self) -> RigidIdState:
        p = self.p
        order = self.filter.order if self.filter is not None else 1
        st = np.zeros(ST_SIZE)
        st[ST_START_T] = math.nan
        return RigidIdState(
            z=np.zeros((p + 3, max(order, 1))),
            prev=np.zeros(PV_SIZE),
            G=np.zeros((p, p)),
            b=np.zeros(p),
            rows=np.zeros((0, 2 + p)),
            pending=np.zeros((0, 2 + p)),
            theta=np.full(p, math.nan),
            cov=np.full((p, p), math.nan),
            cov_plain=np.full((p, p), math.nan),
            active=np.zeros(p),
            stats=st,
        )

    def restart_filters(self, state: RigidIdState) -> RigidIdState:
        """After a break in the data (a gap, a resume): the filters start again, the
        estimate and its rows are kept."""
        fresh = self.initial_state()
        st = state.stats.copy()
        st[ST_START_T] = math.nan
        st[ST_PHASE] = 0.0
        return RigidIdState(fresh.z, fresh.prev, state.G, state.b, state.rows, state.pending,
                            state.theta, state.cov, state.cov_plain, state.active, st)  # fmt: skip

    def adopt(self, state: RigidIdState, names: Sequence[str]) -> RigidIdState:
        """The state of an identifier of another design (a rate change mid-stream: the
        columns ``names``) carried into this one: the identified parameters, their
        information and rows kept by name (in physical units, whatever the rate), the
        filters restarted. A column this design has and the other had not starts empty;
        one it no longer has is dropped."""
        fresh = self.initial_state()
        old = {n: i for i, n in enumerate(names)}
        pairs = [(i, old[n]) for i, n in enumerate(self.names) if n in old]
        new_i = np.array([a for a, _ in pairs], dtype=np.intp)
        old_i = np.array([b for _, b in pairs], dtype=np.intp)
        for attr in ("G", "cov", "cov_plain"):
            getattr(fresh, attr)[np.ix_(new_i, new_i)] = getattr(state, attr)[np.ix_(old_i, old_i)]
        for attr in ("b", "theta", "active"):
            getattr(fresh, attr)[new_i] = getattr(state, attr)[old_i]
        kept = np.vstack([state.rows, state.pending])
        rows = np.zeros((len(kept), 2 + self.p))
        rows[:, :2] = kept[:, :2]
        rows[:, 2 + new_i] = kept[:, 2 + old_i]
        fresh.rows = rows[-self._keep :]
        keep = (ST_VMAX, ST_ROWS, ST_REVERSALS, ST_SIGN, ST_MOVING_T, ST_BANDWIDTH, ST_S2,
                ST_NEFF, ST_SAMPLES)  # fmt: skip
        for k in keep:
            fresh.stats[k] = state.stats[k]
        fresh.stats[ST_SINCE_HAC] = self.params.hac_every_s  # refresh at the next rows
        return fresh

    # ------------------------------------------------------------------ step
    def step(
        self,
        state: RigidIdState,
        t: F64,
        q: F64,
        tau: F64,
        qd: F64 | None = None,
        qdd: F64 | None = None,
        learn: NDArray[np.bool_] | None = None,
    ) -> tuple[RigidIdState, RigidIdRecord]:
        """One block of samples (time ``t``, position ``q``, effort ``tau``; the CNC's
        velocity ``qd`` and acceleration ``qdd`` when the design uses them; ``learn``:
        where the identifier may learn, default everywhere)."""
        pr = self.params
        n = len(t)
        arrays = self._inputs(t, q, tau, qd, qdd, learn)
        new = self._copy(state)
        t_out = np.asarray(arrays["t"], dtype=np.float64) - pr.sample_time
        fresh = new.prev[PV_SEEN] == 0.0
        kin, tau_raw = self._kinematics(new, arrays, n, t_out)
        # the columns learnt from (the sign of the velocity), the effort, the velocity and
        # the Coulomb column of the force (0 at standstill), filtered alike
        v_static = pr.static_rel * state.stats[ST_VMAX]
        if self._fused(new, fresh, n):  # the plain design: one kernel, the same numbers
            filt = np.empty((n, self.p + 3))
            still = np.empty(n, dtype=np.bool_)
            assert self.filter is not None
            _front_kernel(kin.qd, kin.qdd, tau_raw, pr.has_mass, v_static, self.filter.b,
                          self.filter.a, new.z, filt, still)  # fmt: skip
        else:
            x_lrn = columns(pr, kin)
            still = np.abs(kin.qd) <= v_static
            x_raw = np.column_stack(
                [x_lrn, tau_raw, kin.qd, np.where(still, 0.0, x_lrn[:, self._fc])]
            )
            filt = self._filtered(new, x_raw, fresh)
        x_all, eff, v_f = filt[:, : self.p], filt[:, self.p], filt[:, self.p + 1]
        x_frc = x_all.copy()
        x_frc[:, self._fc] = filt[:, self.p + 2]
        theta0, cov0 = state.theta.copy(), state.cov.copy()
        force, sd = self._force(eff, x_frc, theta0, cov0, state.stats[ST_S2])
        if v_static > 0 and math.isfinite(theta0[self._fc]):
            # standstill: the static friction is anywhere within +-Fc (its sd, uniform)
            sd = np.where(still, np.hypot(sd, abs(theta0[self._fc]) / math.sqrt(3.0)), sd)
        self._learn(new, t_out, v_f, x_all, eff, arrays["learn"])
        return new, self._record(new, t_out, force, sd, eff)

    def _fused(self, st: RigidIdState, fresh: bool, n: int) -> bool:
        """May this block take :func:`_front_kernel`: a design without a report's effects,
        filtered, its filters started (a fresh start sets them from the first row) and of
        this design's width, and samples to take."""
        return (
            not self.params.effects
            and self.filter is not None
            and not fresh
            and n > 0
            and st.z.shape[0] == self.p + 3
        )

    def _inputs(self, t: F64, q: F64, tau: F64, qd: F64 | None, qdd: F64 | None,
                learn: NDArray[np.bool_] | None) -> dict[str, NDArray[Any]]:  # fmt: skip
        pr = self.params
        n = len(t)
        out: dict[str, NDArray[Any]] = {"t": t, "q": q, "tau": tau}
        for name, v, need in (("qd", qd, pr.velocity == "given"),
                              ("qdd", qdd, pr.acceleration == "given")):  # fmt: skip
            if need and v is None:
                raise ParameterError(name, f"the CNC's {name} (the design uses it)", None)
            out[name] = np.zeros(n) if v is None else v
        out["learn"] = np.ones(n, dtype=np.bool_) if learn is None else np.asarray(learn, bool)
        for k, v in out.items():
            if len(v) != n:
                raise ParameterError(k, f"{n} samples (as t)", len(v))
            out[k] = np.ascontiguousarray(v, dtype=np.bool_ if k == "learn" else np.float64)
        return out

    @staticmethod
    def _copy(s: RigidIdState) -> RigidIdState:
        return RigidIdState(s.z.copy(), s.prev.copy(), s.G.copy(), s.b.copy(), s.rows,
                            s.pending, s.theta.copy(), s.cov.copy(), s.cov_plain.copy(),
                            s.active.copy(), s.stats.copy())  # fmt: skip

    def _kinematics(
        self, st: RigidIdState, a: dict[str, NDArray[Any]], n: int, t_out: F64
    ) -> tuple[_Rows, F64]:
        pr = self.params
        out = KinematicsOut(np.empty(n), np.empty(n), np.empty(n), np.empty(n), np.empty(n))
        inp = KinematicsIn(
            q=a["q"],
            tau=a["tau"],
            vg=a["qd"],
            ag=a["qdd"],
            given_v=pr.velocity == "given",
            given_a=pr.acceleration == "given",
            ts=float(pr.sample_time),
        )
        _kinematics_kernel(inp, st.prev, out)
        q, v, acc, jerk, tau = out
        if math.isnan(st.stats[ST_START_T]) and n:
            st.stats[ST_START_T] = float(a["t"][0])
        return _Rows(t_out, q, v, acc, jerk), tau

    def _filtered(self, st: RigidIdState, x: F64, fresh: bool) -> F64:
        """P on every column (none below 100 Hz); a ``fresh`` filter (nothing seen since
        the start or a restart) starts in the steady state of its first input."""
        if self.filter is None or not len(x):
            return x
        if st.z.shape[0] < x.shape[1]:  # a state kept before the force's own column
            st.z = np.vstack([st.z, np.zeros((x.shape[1] - st.z.shape[0], st.z.shape[1]))])
        if fresh:
            for c in range(x.shape[1]):
                v0 = float(x[0, c]) if np.isfinite(x[0, c]) else 0.0
                st.z[c] = self.filter.initial_state(v0)
        out = np.empty_like(x)
        xx = np.ascontiguousarray(x, dtype=np.float64)  # not finite: 0, in the kernel
        _filter_columns(xx, self.filter.b, self.filter.a, st.z, out)
        return out

    def _force(self, eff: F64, x: F64, theta: F64, cov: F64, s2: float) -> tuple[F64, F64]:
        """The process force with the estimate before the block, and its uncertainty."""
        ok = np.isfinite(theta)
        if not ok.any():
            return np.full(len(eff), math.nan), np.full(len(eff), math.nan)
        xa = x[:, ok]
        force = eff - xa @ theta[ok]
        c = cov[np.ix_(ok, ok)]
        var = np.einsum("ij,jk,ik->i", xa, c, xa) if np.all(np.isfinite(c)) else np.nan
        return force, np.sqrt(np.maximum(var + s2, 0.0))

    # ------------------------------------------------------------------ learning
    def _learn(self, st: RigidIdState, t: F64, v_f: F64, x: F64, eff: F64,
               learn: NDArray[np.bool_]) -> None:  # fmt: skip
        pr = self.params
        n = len(t)
        phase = int(st.stats[ST_PHASE])
        first = (-phase) % pr.decimation
        st.stats[ST_PHASE] = (phase + n) % pr.decimation
        st.stats[ST_SAMPLES] += n
        if first >= n:
            return
        use = np.empty((n - first + pr.decimation - 1) // pr.decimation, dtype=np.intp)
        m, vmax = _rows_kernel(first, pr.decimation, v_f, t, x, learn, float(st.stats[ST_VMAX]),
                               pr.moving_rel, st.stats[ST_START_T] + pr.settle_s, use)  # fmt: skip
        st.stats[ST_VMAX] = vmax
        use = use[:m]
        if not m:
            return
        self._count_reversals(st, v_f[use])
        xr, yr = x[use], eff[use]
        w = self.lam ** np.arange(m - 1, -1, -1, dtype=np.float64)
        decay = self.lam**m
        st.G = decay * st.G + (xr * w[:, None]).T @ xr
        st.b = decay * st.b + (xr * w[:, None]).T @ yr
        # the kept rows grow at the refresh only (a copy of the whole buffer per block
        # would cost more than the block's own work)
        st.pending = np.vstack([st.pending, np.column_stack([t[use], yr, xr])])
        st.stats[ST_ROWS] += m
        st.stats[ST_MOVING_T] += m * pr.row_time
        st.stats[ST_SINCE_HAC] += m * pr.row_time
        if st.stats[ST_ROWS] < max(pr.min_rows, 2 * self.p):
            return
        if st.stats[ST_SINCE_HAC] >= pr.hac_every_s or not np.any(st.active):
            self._refresh(st)
        else:
            st.theta = _solve(st.G, st.b, st.active.astype(bool))

    @staticmethod
    def _count_reversals(st: RigidIdState, v: F64) -> None:
        s = np.sign(v)
        prev = st.stats[ST_SIGN]
        seq = np.concatenate([[prev], s]) if prev != 0 else s
        st.stats[ST_REVERSALS] += int(np.count_nonzero(seq[1:] != seq[:-1]))
        st.stats[ST_SIGN] = float(s[-1])

    def _refresh(self, st: RigidIdState) -> None:
        """The identifiable columns, the estimate and its Newey-West covariance."""
        st.stats[ST_SINCE_HAC] = 0.0
        active = _ordered_active(st.G)
        st.active = active.astype(np.float64)
        st.theta = _solve(st.G, st.b, active)
        st.rows = np.vstack([st.rows, st.pending])[-self._keep :]
        st.pending = st.pending[:0]
        rows = st.rows
        m = len(rows)
        w = self.lam ** np.arange(m - 1, -1, -1, dtype=np.float64)
        idx = np.flatnonzero(active)
        x = rows[:, 2:][:, idx]
        e = rows[:, 1] - x @ st.theta[idx]
        n_eff = effective_rows(w)
        band = andrews_bandwidth(e, n_eff)
        p = self.p
        st.cov = np.full((p, p), math.nan)
        st.cov_plain = np.full((p, p), math.nan)
        try:
            cov, plain, band = hac_covariance(x, e, w, band)
        except ParameterError:
            return
        st.cov[np.ix_(idx, idx)] = cov
        st.cov_plain[np.ix_(idx, idx)] = plain
        st.stats[ST_BANDWIDTH] = band
        st.stats[ST_S2] = float(np.sum(w * e * e) / np.sum(w))
        st.stats[ST_NEFF] = n_eff

    # ------------------------------------------------------------------ output
    def _record(self, st: RigidIdState, t: F64, force: F64, sd: F64, eff: F64) -> RigidIdRecord:
        th = st.theta
        lower, upper, half_plain, excited, directions, differs = self._intervals(st)
        return RigidIdRecord(
            t=t, force=force, force_sd=sd, effort=eff, theta=th.copy(),
            lower=lower.copy(), upper=upper.copy(), half_plain=half_plain.copy(),
            excited=excited.copy(),
            rows=int(st.stats[ST_ROWS]), reversals=int(st.stats[ST_REVERSALS]),
            moving_time=float(st.stats[ST_MOVING_T]), bandwidth=int(st.stats[ST_BANDWIDTH]),
            residual_rms=float(math.sqrt(st.stats[ST_S2])),
            directions=dict(directions),
            direction_differs=differs,
        )  # fmt: skip

    def _intervals(self, st: RigidIdState) -> _Intervals:
        """The estimate's intervals, excitation and friction by direction: a function of
        the estimate, its covariances, the reversals and the residual's variance only,
        so those of the block before when these have not changed (most blocks: the
        estimate moves only on the blocks it learns from)."""
        key = (st.theta.tobytes(), st.cov.tobytes(), st.cov_plain.tobytes(),
               float(st.stats[ST_REVERSALS]), float(st.stats[ST_S2]))  # fmt: skip
        if self._last_intervals is not None and self._last_intervals[0] == key:
            return self._last_intervals[1]
        half = self._z * np.sqrt(np.diag(st.cov))
        th = st.theta
        dirs: dict[str, tuple[float, float]] = {}
        differs = False
        if np.all(np.isfinite(th[self._fc : self._fc + 2])):
            dirs = direction_friction(self.names, th, st.cov)
            # Fc_pos - Fc_neg = 2 offset (+ a report's dir_pos): its interval
            off = self._fc + 1
            differs = bool(abs(th[off]) > half[off]) and st.stats[ST_REVERSALS] >= 1
        out: _Intervals = (
            th - half, th + half, self._z * np.sqrt(np.diag(st.cov_plain)),
            self._excited(st, half), {k: (v, self._z * s) for k, (v, s) in dirs.items()},
            differs,
        )  # fmt: skip
        self._last_intervals = (key, out)
        return out

    def _excited(self, st: RigidIdState, half: F64) -> NDArray[np.bool_]:
        """Per column: a base parameter whose 95 % half-width is at most ``excited_rel``
        of its value (the offset's: of Fc); the friction parameters only once the axis
        has moved both ways (in one direction the sign and the offset are one column,
        and a sweep along the travel mixes speed and position)."""
        th = st.theta
        ex = np.zeros(self.p, dtype=np.bool_)
        nb = self._fc + 2  # the base columns end with Fc, offset
        scale = np.abs(th[:nb])
        scale[nb - 1] = abs(th[self._fc])
        with np.errstate(invalid="ignore"):
            ex[:nb] = (half[:nb] <= self.params.excited_rel * scale) & np.isfinite(half[:nb])
        if st.stats[ST_REVERSALS] < 1:
            ex[nb - 3 : nb] = False
        if not st.stats[ST_S2] > 0:  # a perfect fit: the effort holds no signal (all 0)
            ex[:] = False
        return ex


def direction_friction(
    names: Sequence[str], theta: F64, cov: F64
) -> dict[str, tuple[float, float]]:
    """The friction level of each direction, :math:`F_{c+} = F_c + \\tau_{off}` and
    :math:`F_{c-} = F_c - \\tau_{off}` (plus a report's ``dir_pos`` for v > 0), each
    with its standard deviation. On moving rows an offset (gravity, an amplifier's
    offset) and a friction that differs by direction are the same columns: these are
    the levels the data determine."""
    i = {n: k for k, n in enumerate(names)}
    out = {}
    for d, sign in (("pos", 1.0), ("neg", -1.0)):
        terms = [(i["Fc"], 1.0), (i["offset"], sign)]
        j = i.get("coulomb_asymmetry.dir_pos")
        if d == "pos" and j is not None and math.isfinite(theta[j]):
            terms.append((j, 1.0))
        val = sum(g * float(theta[k]) for k, g in terms)
        var = sum(g * h * float(cov[k, m]) for k, g in terms for m, h in terms)
        out[f"Fc_{d}"] = (val, math.sqrt(max(var, 0.0)))
    return out


__all__ = [
    "BASE",
    "LiveEffect",
    "RigidIdParams",
    "RigidIdRecord",
    "RigidIdState",
    "RigidIdentifier",
    "columns",
    "direction_friction",
    "rigid_design",
]
