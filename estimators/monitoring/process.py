r"""Process monitoring: teach-in limits per program block, and three event detectors.

What a shop's process monitor does (Caron TMAC, ToolScope, ARTIS): over the first good
parts it learns, per *(tool, program, block)*, an envelope of the monitored signal, then
raises an alarm when the signal leaves it. Here the signal is the resultant of the
cutting force estimated from the X/Y drives (the observers' :math:`\hat F_x, \hat F_y`,
never the true force) and its once-per-revolution pattern read with the spindle angle.

Signals, per sample :math:`k` (``L`` samples per spindle revolution, from the spindle
angle's increment at the block's start):

* :math:`f_k = \sqrt{\hat F_x^2 + \hat F_y^2}`, the force magnitude (independent of the
  feed direction);
* :math:`\bar f_k = \frac1L\sum_{i<L} f_{k-i}`, its mean over the last revolution;
* :math:`\rho_k = 2\sum_{i<L} f_{k-i} e^{-j\psi_{k-i}} / \sum_{i<L} f_{k-i}`, the spindle
  harmonic of seed003 (8) over the last revolution, normalised by the mean force: the
  *once-per-revolution pattern*. Runout gives it a steady value; a flute that loses its
  edge changes it by a large step (its chip goes to the next flute);
* :math:`d_k = |\rho_k - \rho_{k-L}|`, the change of the pattern over one revolution.

Teach-in (per (tool, program, block), over the first ``teach_parts`` executions at 100 %
feed override): the block's time since its start, counted in *nominal* time
(:math:`\sum` override :math:`\cdot T_s`, so a bin stays at the same place of the path
whatever the override), is cut into bins of ``bin_s``. Per bin: the mean, spread and
minimum of :math:`\bar f`, the peak of :math:`f`, the largest :math:`d`. From them:

* bands on :math:`\bar f`: mean :math:`\pm` ``band_factor`` :math:`\cdot\max(\sigma,`
  ``band_rel`` :math:`\cdot` mean) (drawn on the force chart);
* the extreme limit on :math:`f`: ``extreme_factor`` times the block's taught peak, and
  never below ``extreme_floor`` [N];
* the breakage threshold on :math:`d`: ``breakage_factor`` times the largest taught
  :math:`d` in the bin and its neighbours, never below ``breakage_floor``.

Limits follow what is known to change the force. *Feed override* :math:`o`: the force
per tooth is :math:`K_c a h + K_e a` with :math:`h \propto o`, so its ratio lies between
1 and :math:`o`; upper limits are scaled by :math:`\max(o, 1)` and lower ones by
:math:`\min(o, 1)` (the monitor does not know the edge share). *Wear*: the expected force
ratio :math:`g` (the wear estimate's expected force increase) multiplies every band and
limit. The caller may give it (from a wear estimator); otherwise the monitor tracks it
per block as an exponential average (weight ``gain_alpha``) of the executed block's mean
:math:`\bar f` over the taught one, updated only after a block at 100 % override that
raised no alarm, clamped to [0.5, 2].

Detectors (each with its reason):

``breakage`` (tooth breakage and chipping)
    :math:`d_k` above its threshold for ``breakage_rev`` of a revolution (at least
    :data:`MIN_BREAKAGE_SAMPLES` samples), evaluated where the
    block is taught as cutting and both windows lie in the block. A broken tooth moves
    the pattern by the order of 1 within one revolution; runout, wear and the feed
    override move it slowly. ``suspected`` (:math:`d_k` above ``suspect_share`` of the
    threshold) is the flag the eccentricity canceller of seed 003 holds its adaptation on
    (the canceller works on this same harmonic and would otherwise "cancel" the breakage).
    It is evaluated only while the mean force is above the lower limit (a missing tool is
    the other detector's).
``collision`` (collision, overload)
    :math:`f_k` above the extreme limit for ``collision_s`` seconds of consecutive
    samples (at least :data:`MIN_COLLISION_SAMPLES`): no cut the program makes comes near
    it.
``missing_tool`` (missing or broken-off tool)
    :math:`\bar f_k` below the lower limit for one revolution and at least ``missing_s``
    seconds, where the block is taught
    as cutting (taught minimum of :math:`\bar f` above ``min_cut_force`` and above
    ``cut_share`` of the block's largest taught mean: past the entry's ramp, where a
    small shift of the entry would move the force a lot). The lower
    limit is the lower band, or ``lower_share`` of the taught minimum if that is lower.

Blocks the program says cannot cut (``step(..., cutting=False)``: a G0 rapid, a tool
change, a spindle start or stop, a dwell, a feed along the tool's axis alone) are watched
by the collision detector only: the CNC knows them, and a signal's error floor there (an
axis accelerating, a spindle running up) would otherwise be taught as a cut and its next
execution judged against it (issue 32: on the machining centre's axes at 5 kHz, 732
false alarms in 17 h, in plunges, rapids and spindle blocks). An industrial monitor is
likewise switched on around the program's cuts only.

Confirmations are physical quantities, the same at every sample rate (issue 32): a
collision's force rises within the contact and stays, so its confirmation is a time; a
breakage's pattern change is a per-revolution statistic that stays high for about a
revolution after the step, so its confirmation is a share of the revolution; a lost
tool's absence lasts the rest of the block while a light intermittent cut's mean,
point-sampled at a few samples per revolution, dips for a few samples as the samples
slide over the teeth, so its confirmation is a time (and never under the revolution
the mean is taken over). Each has a floor in samples: below it a confirmation would
rest on one or two samples of noise (docs/monitoring.md, "Confirmations in time and
revolutions").

Each detector alarms at most once per block execution (latched until the next block).
The detectors run per sample inside one numba kernel, so their delays do not depend on
the block size a caller steps with.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit

from common.arrays import F64
from common.event_kinds import ProcessEventKind
from estimators.errors import ParameterError, require_in, require_positive

#: the fewest consecutive samples that confirm a breakage / a collision, whatever the rate
MIN_BREAKAGE_SAMPLES = 3
MIN_COLLISION_SAMPLES = 2
#: the detectors, in the order of their ids in the alarm table
DETECTORS: tuple[ProcessEventKind, ...] = tuple(ProcessEventKind)
#: teach arrays per (segment, bin)
_TEACH = ("cnt", "m_sum", "m_sq", "m_min", "pk_sum", "pk_max", "d_max")
#: per-execution accumulators per bin
_CUR = ("c_n", "c_sum", "c_min", "c_pk", "c_d")
#: scalar running state (one row)
_RUN = (
    "seg", "k_in", "tau", "L", "s0", "sre", "sim", "head", "run_b", "run_c", "run_m",
    "latch_b", "latch_c", "latch_m", "blk_sum", "blk_ref", "psi_prev", "override",
    "alarmed",
)  # fmt: skip
_R = {name: i for i, name in enumerate(_RUN)}
_T = {name: i for i, name in enumerate(_TEACH)}
_C = {name: i for i, name in enumerate(_CUR)}


@dataclass(frozen=True)
class MonitorParams:
    """Settings of the teach-in and the detectors (see the module docstring).

    Parameters
    ----------
    sample_time : float
        Drive sample time [s].
    teach_parts : int
        Good executions per (tool, program, block) taught before watching (N).
    bin_s : float
        Bin width of the envelope in nominal time [s].
    max_bins, max_segments : int
        Sizes of the tables (blocks longer than ``max_bins * bin_s`` share the last bin).
    band_factor, band_rel : float
        Band half-width: ``band_factor * max(sigma, band_rel * mean)``.
    lower_share : float
        The missing-tool limit is never above this share of the taught minimum.
    extreme_factor, extreme_floor : float
        Extreme limit: ``max(extreme_factor * taught peak, extreme_floor)`` [N].
    min_cut_force, cut_share : float
        A bin counts as cutting when its taught minimum mean force exceeds this [N] and
        ``cut_share`` of the block's largest taught mean (past the entry's ramp).
    breakage_factor, breakage_floor : float
        Breakage threshold on the pattern change ``d``.
    suspect_share : float
        ``suspected`` when ``d`` exceeds this share of the threshold.
    breakage_rev : float
        Share of a spindle revolution the pattern change stays above its threshold to
        make a breakage alarm (at least :data:`MIN_BREAKAGE_SAMPLES` samples).
    collision_s : float
        Time the force stays above the extreme limit to make a collision alarm [s] (at
        least :data:`MIN_COLLISION_SAMPLES` samples).
    missing_s : float
        Time the revolution's mean stays below the missing-tool limit to make an alarm
        [s] (never less than the revolution the mean is taken over).
    gain_alpha : float
        Weight of one block in the tracked force ratio (0 keeps it at 1).
    max_revolution_samples : int
        Longest revolution the ring buffers hold [samples].
    """

    sample_time: float = 2e-4
    teach_parts: int = 5
    bin_s: float = 0.025
    max_bins: int = 512
    max_segments: int = 64
    band_factor: float = 4.0
    band_rel: float = 0.15
    lower_share: float = 0.5
    extreme_factor: float = 2.0
    extreme_floor: float = 40.0
    min_cut_force: float = 5.0
    cut_share: float = 0.3
    breakage_factor: float = 3.0
    breakage_floor: float = 0.1
    suspect_share: float = 0.5
    breakage_rev: float = 0.125
    collision_s: float = 4e-4
    missing_s: float = 0.03
    gain_alpha: float = 0.2
    max_revolution_samples: int = 8192

    def __post_init__(self) -> None:
        require_positive("sample_time", self.sample_time)
        for name in ("teach_parts", "max_bins", "max_segments", "max_revolution_samples"):
            v = getattr(self, name)
            if int(v) != v or v < 1:
                raise ParameterError(name, "an integer >= 1", v)
        for name in ("bin_s", "band_factor", "extreme_factor", "breakage_factor"):
            require_positive(name, getattr(self, name))
        for name in ("band_rel", "lower_share", "suspect_share", "gain_alpha", "cut_share"):
            require_in(name, getattr(self, name), 0.0, 1.0)
        for name in ("extreme_floor", "min_cut_force", "breakage_floor"):
            require_positive(name, getattr(self, name))
        require_in("breakage_rev", self.breakage_rev, 0.0, 1.0)
        for name in ("collision_s", "missing_s"):
            require_in(name, getattr(self, name), 0.0, 1.0)

    def packed(self) -> F64:
        return np.array(
            [
                self.sample_time, self.teach_parts, self.bin_s, self.band_factor,
                self.band_rel, self.lower_share, self.extreme_factor, self.extreme_floor,
                self.min_cut_force, self.breakage_factor, self.breakage_floor,
                self.suspect_share, self.breakage_rev, self.collision_s,
                self.gain_alpha, self.cut_share, self.missing_s,
            ]
        )  # fmt: skip


@dataclass
class Alarm:
    """One alarm: detector, the sample (index in the monitor's own count), the segment
    key and the statistic beside its limit."""

    detector: ProcessEventKind
    sample: int
    tool: int
    program: str
    line: int
    value: float
    limit: float


@dataclass
class MonitorRecord:
    """Per-sample outputs of one step: the signals, the limits in force and the flags.

    ``f`` force magnitude, ``f_mean`` its mean over a revolution, ``lower``/``upper``
    bands on ``f_mean``, ``extreme`` limit on ``f``, ``pattern`` (``d``) and its
    ``pattern_limit``, ``suspected`` (breakage suspected), ``teaching`` [N or -];
    limits are NaN where none applies (teaching, air).
    """

    f: F64
    f_mean: F64
    lower: F64
    upper: F64
    extreme: F64
    pattern: F64
    pattern_limit: F64
    suspected: np.ndarray
    teaching: bool
    alarms: list[Alarm]


@njit(cache=True)
def _bin_val(a: F64, s: int, b: int, nb: int, use_max: bool) -> float:  # pragma: no cover
    """Max (or min) of ``a[s, b-1..b+1]`` over bins taught (the neighbours absorb a
    small shift of the path from part to part)."""
    v = a[s, b]
    for bb in (b - 1, b + 1):
        if 0 <= bb < nb:
            v = max(v, a[s, bb]) if use_max else min(v, a[s, bb])
    return v


@njit(cache=True)
def _reset_block(run: F64, cur: F64, nb: int) -> None:  # pragma: no cover
    """A new block execution: its scalar state (``_RUN``) and per-bin accumulators
    (``_CUR``) cleared."""
    c_n = cur[0]
    c_sum = cur[1]
    c_min = cur[2]
    c_pk = cur[3]
    c_d = cur[4]
    run[1] = 0.0  # k_in
    run[2] = 0.0  # tau
    run[3] = 0.0  # L unknown until two angles are seen
    for i in range(4, 14):
        run[i] = 0.0
    run[14] = 0.0
    run[15] = 0.0
    run[18] = 0.0
    for b in range(nb):
        c_n[b] = 0.0
        c_sum[b] = 0.0
        c_min[b] = 1e300
        c_pk[b] = 0.0
        c_d[b] = 0.0


@njit(cache=True)
def _samples_per_rev(psi_k: float, run: F64, lmax: int) -> int:  # pragma: no cover
    """Samples per revolution ``L`` from the spindle angle's increment (0 until two angles
    are seen in the block)."""
    kin = int(run[1])
    # samples per revolution from the spindle angle's increment
    if kin > 0 and run[3] == 0.0:
        dpsi = psi_k - run[16]
        if dpsi > 0.0:
            run[3] = float(min(max(round(2.0 * math.pi / dpsi), 4), lmax))
    run[16] = psi_k
    return int(run[3])


@njit(cache=True)
def _revolution(
    f: float, psi_k: float, L: int, run: F64, fbuf: F64, rbuf: F64
) -> tuple[float, float]:  # pragma: no cover
    """The mean force over the last revolution and the change of the once-per-revolution
    pattern from one revolution to the next (NaN until enough samples)."""
    fm = math.nan
    d = math.nan
    if L > 0:
        h = int(run[7])
        # running sums over the last revolution (the ring holds L samples)
        if run[1] >= L + 1:
            run[4] -= fbuf[0, h]
            run[5] -= fbuf[1, h]
            run[6] -= fbuf[2, h]
        c = math.cos(psi_k)
        s = math.sin(psi_k)
        fbuf[0, h] = f
        fbuf[1, h] = f * c
        fbuf[2, h] = -f * s
        run[4] += f
        run[5] += f * c
        run[6] += -f * s
        if run[1] >= L:
            fm = run[4] / L
            # seed003 (8), normalised by the mean: the once-per-revolution pattern
            rre = 2.0 * run[5] / run[4] if run[4] > 0.0 else 0.0
            rim = 2.0 * run[6] / run[4] if run[4] > 0.0 else 0.0
            if run[1] >= 2 * L:
                d = math.hypot(rre - rbuf[0, h], rim - rbuf[1, h])
            rbuf[0, h] = rre
            rbuf[1, h] = rim
        run[7] = (h + 1) % L
    return fm, d


@njit(cache=True)
def _teach_sample(cur: F64, b: int, f: float, fm: float, d: float) -> None:  # pragma: no cover
    """One sample into this execution's accumulators of bin ``b``."""
    c_n = cur[0]
    c_sum = cur[1]
    c_min = cur[2]
    c_pk = cur[3]
    c_d = cur[4]
    if not math.isnan(fm):
        c_n[b] += 1.0
        c_sum[b] += fm
        c_min[b] = min(c_min[b], fm)
    c_pk[b] = max(c_pk[b], f)
    if not math.isnan(d):
        c_d[b] = max(c_d[b], d)


@njit(cache=True)
def _limits(
    pr: F64,
    tt: F64,
    seg_pk: F64,
    seg: int,
    b: int,
    up: float,
    lo_s: float,
    cut_lvl: float,
) -> tuple[float, float, float, float, float]:  # pragma: no cover
    """``(extreme, lower, upper, pattern_limit, count taught)`` of bin ``b`` of segment
    ``seg`` (lower, upper and pattern limit NaN where none applies)."""
    t_cnt = tt[0]
    t_msum = tt[1]
    t_msq = tt[2]
    t_mmin = tt[3]
    t_dmax = tt[6]
    kband = pr[3]
    brel = pr[4]
    lshare = pr[5]
    xfac = pr[6]
    xfloor = pr[7]
    bfac = pr[9]
    bfloor = pr[10]
    nb = t_cnt.shape[1]
    lo = math.nan
    hi = math.nan
    dl = math.nan
    # extreme limit on f (the block's taught peak)
    ex = max(xfac * seg_pk[seg], xfloor) * up
    cnt = t_cnt[seg, b]
    if cnt > 0.0:
        mean = t_msum[seg, b] / cnt
        var = max(t_msq[seg, b] / cnt - mean * mean, 0.0)
        half = kband * max(math.sqrt(var), brel * mean)
        hi = (mean + half) * up
        mmin = _bin_val(t_mmin, seg, b, nb, False)
        lo = min(mean - half, lshare * mmin) * lo_s
        if mmin > cut_lvl:
            dl = max(bfac * _bin_val(t_dmax, seg, b, nb, True), bfloor)
    return ex, lo, hi, dl, cnt


@njit(cache=True)
def _confirm_samples(seconds: float, ts: float, floor: int) -> int:  # pragma: no cover
    """A confirmation time in samples of the rate: rounded up, at least ``floor``."""
    return max(floor, math.ceil(seconds / ts - 1e-9))


@njit(cache=True)
def _collision(
    k: int, f: float, ex: float, nco: int, run: F64, alarms: F64, na: int
) -> int:  # pragma: no cover
    """Collision / overload: ``f`` over the extreme limit for ``nco`` samples; returns
    the alarm rows written so far."""
    if f > ex:
        run[9] += 1.0
    else:
        run[9] = 0.0
    if run[9] >= nco and run[12] == 0.0:
        run[12] = 1.0
        alarms[na, 0] = k
        alarms[na, 1] = 1
        alarms[na, 2] = f
        alarms[na, 3] = ex
        na += 1
    return na


@njit(cache=True)
def _breakage(
    k: int,
    fm: float,
    d: float,
    lo: float,
    dl: float,
    nbk: int,
    sshare: float,
    run: F64,
    o_sus: np.ndarray,
    alarms: F64,
    na: int,
) -> int:  # pragma: no cover
    """Breakage / chipping: the pattern's change over its limit for ``nbk`` samples where
    the block cuts (suspected over ``sshare`` of it); returns the alarm rows written."""
    if not math.isnan(dl) and not math.isnan(d) and fm >= lo:
        if d > sshare * dl:
            o_sus[k] = 1
        if d > dl:
            run[8] += 1.0
        else:
            run[8] = 0.0
        if run[8] >= nbk and run[11] == 0.0:
            run[11] = 1.0
            alarms[na, 0] = k
            alarms[na, 1] = 0
            alarms[na, 2] = d
            alarms[na, 3] = dl
            na += 1
    return na


@njit(cache=True)
def _missing_tool(
    k: int, fm: float, lo: float, dl: float, L: int, nmt: int, run: F64, alarms: F64, na: int
) -> int:  # pragma: no cover
    """Missing tool: below the lower limit for one revolution and at least ``nmt``
    samples where the block cuts; returns the alarm rows written so far."""
    if not math.isnan(dl) and not math.isnan(fm) and fm < lo:
        run[10] += 1.0
    else:
        run[10] = 0.0
    if L > 0 and run[10] >= max(L, nmt) and run[13] == 0.0:
        run[13] = 1.0
        alarms[na, 0] = k
        alarms[na, 1] = 2
        alarms[na, 2] = fm
        alarms[na, 3] = lo
        na += 1
    return na


class MonitorChunk(NamedTuple):
    """One chunk of one block execution as :func:`_monitor_kernel` reads it (read only)."""

    fx: F64  # (n,) estimated cutting force of the X drive [N]
    fy: F64  # (n,) of the Y drive [N]
    psi: F64  # (n,) spindle angle [rad]
    seg: int  # the (tool, program, line) segment's row in the tables
    new_block: bool  # the chunk starts a new execution of the block
    override: float  # feed override of the execution (1 = 100 %)
    gain: float  # expected force ratio (wear estimate or the tracked one)
    teach: bool  # teaching this execution (not yet taught, 100 % override)
    taught: bool  # the segment is taught: limits and detectors apply
    cutting: bool  # the CNC says the block can cut (else the collision limit only)


class MonitorArrays(NamedTuple):
    """The monitor's state arrays, updated in place by :func:`_monitor_kernel`."""

    teach: F64  # (len(_TEACH), segments, bins) the teach tables
    current: F64  # (len(_CUR), bins) this execution's per-bin accumulators
    peak: F64  # (segments,) the block's taught peak of f
    mean_peak: F64  # (segments,) the block's largest taught mean of f_mean
    run: F64  # (len(_RUN),) the scalar running state
    fbuf: F64  # (3, max rev samples) ring of f, f cos psi, -f sin psi
    rbuf: F64  # (2, max rev samples) ring of the pattern rho (re, im)


class MonitorOut(NamedTuple):
    """The kernel's per-sample outputs (filled in place; see :class:`MonitorRecord`)."""

    f: F64  # (n,) force magnitude [N]
    f_mean: F64  # (n,) its mean over the last revolution [N]
    lower: F64  # (n,) lower band on f_mean [N]
    upper: F64  # (n,) upper band on f_mean [N]
    extreme: F64  # (n,) extreme limit on f [N]
    pattern: F64  # (n,) change d of the once-per-revolution pattern [-]
    pattern_limit: F64  # (n,) its breakage threshold [-]
    suspected: np.ndarray  # (n,) uint8, breakage suspected
    alarms: F64  # (3 n, 4) rows [k, detector, value, limit]


@njit(cache=True)
def _monitor_kernel(
    inp: MonitorChunk, pr: F64, st: MonitorArrays, out: MonitorOut
) -> int:  # pragma: no cover
    """One chunk of one block execution; returns the number of alarm rows written.

    ``out.alarms[i] = [k, detector, value, limit]``. ``pr`` the packed settings
    (:meth:`MonitorParams.packed`); ``st.teach`` the teach tables (``_TEACH`` by segment by
    bin), ``st.current`` this execution's per-bin accumulators (``_CUR``), ``st.run`` the
    scalar state (``_RUN``), ``st.fbuf`` the ring of ``f, f cos psi, -f sin psi``,
    ``st.rbuf`` the ring of the pattern ``rho``.
    """
    fx, fy, psi, seg = inp.fx, inp.fy, inp.psi, inp.seg
    new_block, override, gain_in = inp.new_block, inp.override, inp.gain
    teach, taught, cutting = inp.teach, inp.taught, inp.cutting
    tt, cur, seg_pk, seg_mpk = st.teach, st.current, st.peak, st.mean_peak
    run, fbuf, rbuf = st.run, st.fbuf, st.rbuf
    o_sus, alarms = out.suspected, out.alarms
    t_cnt = tt[0]
    t_msum = tt[1]
    o_f = out.f
    o_fm = out.f_mean
    o_lo = out.lower
    o_hi = out.upper
    o_ex = out.extreme
    o_d = out.pattern
    o_dl = out.pattern_limit
    ts = pr[0]
    bin_s = pr[2]
    mincut = pr[8]
    sshare = pr[11]
    brev = pr[12]
    nco = _confirm_samples(pr[13], ts, MIN_COLLISION_SAMPLES)
    nmt = _confirm_samples(pr[16], ts, 1)
    cut_lvl = max(mincut, pr[15] * seg_mpk[seg])
    nb = t_cnt.shape[1]
    lmax = fbuf.shape[1]
    na = 0
    if new_block:
        _reset_block(run, cur, nb)
    up = max(override, 1.0) * gain_in
    lo_s = min(override, 1.0) * gain_in
    for k in range(fx.shape[0]):
        f = math.sqrt(fx[k] * fx[k] + fy[k] * fy[k])
        L = _samples_per_rev(psi[k], run, lmax)
        b = min(int(run[2] / bin_s), nb - 1)
        fm, d = _revolution(f, psi[k], L, run, fbuf, rbuf)
        o_f[k] = f
        o_fm[k] = fm
        o_d[k] = d
        o_sus[k] = 0
        lo = math.nan
        hi = math.nan
        ex = math.nan
        dl = math.nan
        if teach:
            _teach_sample(cur, b, f, fm, d)
        elif taught:
            ex, lo, hi, dl, cnt = _limits(pr, tt, seg_pk, seg, b, up, lo_s, cut_lvl)
            if not cutting:
                # the CNC says this block cannot cut: only the extreme limit applies
                lo = math.nan
                hi = math.nan
                dl = math.nan
            na = _collision(k, f, ex, nco, run, alarms, na)
            nbk = max(MIN_BREAKAGE_SAMPLES, math.ceil(brev * L - 1e-9))
            na = _breakage(k, fm, d, lo, dl, nbk, sshare, run, o_sus, alarms, na)
            na = _missing_tool(k, fm, lo, dl, L, nmt, run, alarms, na)
            # the block's mean against the taught one (the tracked force ratio)
            if cnt > 0.0 and not math.isnan(fm) and not math.isnan(dl):
                run[14] += fm
                run[15] += t_msum[seg, b] / cnt
        o_lo[k] = lo
        o_hi[k] = hi
        o_ex[k] = ex
        o_dl[k] = dl
        run[1] += 1.0
        run[2] += override * ts
    if na > 0:
        run[18] = 1.0
    return na


def _key(tool: int, program: str, line: int) -> tuple[int, str, int]:
    return int(tool), str(program), int(line)


class ProcessMonitor:
    """Teach-in envelopes and the breakage, collision and missing-tool detectors.

    The state is explicit (:meth:`initial_state`, a dict of arrays that a checkpoint can
    keep); :meth:`step` processes a chunk of samples inside one program block execution.

    Examples
    --------
    >>> mon = ProcessMonitor(MonitorParams())
    >>> st = mon.initial_state()
    """

    def __init__(self, params: MonitorParams | None = None) -> None:
        self.params = params if params is not None else MonitorParams()
        self._pr = self.params.packed()

    def initial_state(self) -> dict[str, np.ndarray]:
        """Nothing taught: every table at zero, no segment known."""
        p = self.params
        s, b = p.max_segments, p.max_bins
        st: dict[str, np.ndarray] = {"teach": np.zeros((len(_TEACH), s, b))}
        st["teach"][_T["m_min"]] = np.inf
        st["current"] = np.zeros((len(_CUR), b))
        st["parts"] = np.zeros(s)
        st["gain"] = np.ones(s)
        st["peak"] = np.zeros(s)
        st["mean_peak"] = np.zeros(s)
        st["key_tool"] = np.full(s, -1, dtype=np.int64)
        st["key_line"] = np.full(s, -1, dtype=np.int64)
        st["key_program"] = np.full(s, "", dtype="<U32")
        st["run"] = np.zeros(len(_RUN))
        st["run"][_R["seg"]] = -1
        st["fbuf"] = np.zeros((3, p.max_revolution_samples))
        st["rbuf"] = np.zeros((2, p.max_revolution_samples))
        st["samples"] = np.zeros(1, dtype=np.int64)
        return st

    def segment(self, state: dict[str, np.ndarray], tool: int, program: str, line: int) -> int:
        """Index of the (tool, program, line) segment, registering it if new."""
        t, prog, ln = _key(tool, program, line)
        if len(prog) > 32:
            raise ParameterError("program", "a name of at most 32 characters", prog)
        kt, kl, kp = state["key_tool"], state["key_line"], state["key_program"]
        hit = np.flatnonzero((kt == t) & (kl == ln) & (kp == prog))
        if hit.size:
            return int(hit[0])
        free = np.flatnonzero(kt < 0)
        if not free.size:
            raise ParameterError(
                "segments", f"at most {self.params.max_segments} (tool, program, line)", t
            )
        i = int(free[0])
        kt[i], kl[i], kp[i] = t, ln, prog
        return i

    def has_room(self, state: dict[str, np.ndarray], tool: int, program: str, line: int) -> bool:
        """True when the (tool, program, line) segment is known or a free one is left
        (:meth:`step` raises :class:`ParameterError` otherwise): a live program with more
        blocks than ``max_segments`` leaves the ones beyond it unwatched, not the monitor
        stopped."""
        t, prog, ln = _key(tool, program, line)
        kt, kl, kp = state["key_tool"], state["key_line"], state["key_program"]
        return bool(((kt == t) & (kl == ln) & (kp == prog)).any() or (kt < 0).any())

    def teaching(self, state: dict[str, np.ndarray], seg: int) -> bool:
        return bool(state["parts"][seg] < self.params.teach_parts)

    def relearn(
        self, state: dict[str, np.ndarray], *, tool: int | None = None, program: str | None = None
    ) -> int:
        """Forget what was taught for a tool and/or a program (both None: everything);
        returns the number of segments reset."""
        sel = state["key_tool"] >= 0
        if tool is not None:
            sel &= state["key_tool"] == int(tool)
        if program is not None:
            sel &= state["key_program"] == str(program)
        for name, i in _T.items():
            state["teach"][i][sel] = np.inf if name == "m_min" else 0.0
        state["parts"][sel] = 0.0
        state["gain"][sel] = 1.0
        state["peak"][sel] = 0.0
        state["mean_peak"][sel] = 0.0
        return int(sel.sum())

    def step(
        self,
        state: dict[str, np.ndarray],
        fx: F64,
        fy: F64,
        psi: F64,
        *,
        tool: int,
        program: str,
        line: int,
        new_block: bool,
        override: float = 1.0,
        gain: float | None = None,
        cutting: bool = True,
    ) -> MonitorRecord:
        """Process one chunk of samples of one program block execution.

        Parameters
        ----------
        state : dict
            From :meth:`initial_state`; updated in place.
        fx, fy : arrays
            Estimated cutting force of the X and Y drives [N].
        psi : array
            Spindle angle [rad].
        tool, program, line : int, str, int
            The CNC's identities of the block.
        new_block : bool
            True when this chunk starts a new execution of a block (the previous one ends).
        override : float
            Feed override (1 = 100 %).
        gain : float, optional
            Expected force ratio from a wear estimate; default the tracked one.
        cutting : bool
            False when the CNC's program says the block cannot cut (a G0 rapid, a tool
            change, a spindle start or stop, a dwell; a feed along the tool's axis alone
            where the stock is cut in the plane): only the collision detector watches it
            (a rapid into a clamp), with the block's taught peak; the bands, the breakage
            and the missing-tool detectors and the tracked force ratio leave it alone, as
            an industrial monitor is switched on only around the program's cuts. Default
            True: every block is judged by its taught force alone.
        """
        fx = np.ascontiguousarray(fx, dtype=np.float64)
        fy = np.ascontiguousarray(fy, dtype=np.float64)
        psi = np.ascontiguousarray(psi, dtype=np.float64)
        if not (fx.shape == fy.shape == psi.shape) or fx.ndim != 1:
            raise ParameterError("fx/fy/psi", "1-D arrays of one length", (fx.shape, fy.shape))
        if not (math.isfinite(override) and 0.0 < override <= 3.0):
            raise ParameterError("override", "a feed override in (0, 3]", override)
        run = state["run"]
        seg = self.segment(state, tool, program, line)
        prev = int(run[_R["seg"]])
        if new_block or prev != seg:
            if prev >= 0:
                self._end_block(state, prev)
            new_block = True
            run[_R["override"]] = override
        run[_R["seg"]] = seg
        ov = float(run[_R["override"]])
        teach = self.teaching(state, seg) and ov == 1.0
        watch = not self.teaching(state, seg)
        g = float(state["gain"][seg]) if gain is None else float(gain)
        n = fx.size
        o = np.empty((7, n))
        out = MonitorOut(
            f=o[0], f_mean=o[1], lower=o[2], upper=o[3], extreme=o[4], pattern=o[5],
            pattern_limit=o[6], suspected=np.zeros(n, dtype=np.uint8),
            alarms=np.zeros((3 * max(n, 1), 4)),
        )  # fmt: skip
        inp = MonitorChunk(
            fx=fx, fy=fy, psi=psi, seg=seg, new_block=bool(new_block), override=ov, gain=g,
            teach=teach, taught=watch, cutting=bool(cutting),
        )  # fmt: skip
        arrays = MonitorArrays(
            teach=state["teach"], current=state["current"], peak=state["peak"],
            mean_peak=state["mean_peak"], run=run, fbuf=state["fbuf"], rbuf=state["rbuf"],
        )  # fmt: skip
        na = _monitor_kernel(inp, self._pr, arrays, out)
        k0 = int(state["samples"][0])
        state["samples"][0] += n
        alarms = [
            Alarm(DETECTORS[int(a[1])], k0 + int(a[0]), int(tool), str(program), int(line),
                  float(a[2]), float(a[3]))
            for a in out.alarms[:na]
        ]  # fmt: skip
        return MonitorRecord(
            f=out.f, f_mean=out.f_mean, lower=out.lower, upper=out.upper, extreme=out.extreme,
            pattern=out.pattern, pattern_limit=out.pattern_limit, suspected=out.suspected,
            teaching=teach, alarms=alarms,
        )  # fmt: skip

    def end_block(self, state: dict[str, np.ndarray]) -> None:
        """Close the current block execution (teach it, or update the force ratio)."""
        seg = int(state["run"][_R["seg"]])
        if seg >= 0:
            self._end_block(state, seg)
            state["run"][_R["seg"]] = -1

    def _end_block(self, state: dict[str, np.ndarray], seg: int) -> None:
        run = state["run"]
        ov = float(run[_R["override"]])
        if self.teaching(state, seg):
            if ov != 1.0:
                return
            t = {name: state["teach"][i, seg] for name, i in _T.items()}
            c = {name: state["current"][i] for name, i in _C.items()}
            used = c["c_n"] > 0
            mean = np.where(used, c["c_sum"] / np.maximum(c["c_n"], 1), 0.0)
            t["cnt"][used] += 1.0
            t["m_sum"][used] += mean[used]
            t["m_sq"][used] += mean[used] ** 2
            np.minimum(t["m_min"], c["c_min"], out=t["m_min"])
            t["pk_sum"] += c["c_pk"]
            np.maximum(t["pk_max"], c["c_pk"], out=t["pk_max"])
            np.maximum(t["d_max"], c["c_d"], out=t["d_max"])
            state["peak"][seg] = float(t["pk_max"].max())
            taught = t["cnt"] > 0
            if taught.any():
                state["mean_peak"][seg] = float((t["m_sum"][taught] / t["cnt"][taught]).max())
            state["parts"][seg] += 1.0
            return
        ref = run[_R["blk_ref"]]
        if ov == 1.0 and run[_R["alarmed"]] == 0.0 and ref > 0.0:
            a = self.params.gain_alpha
            ratio = run[_R["blk_sum"]] / ref
            g = state["gain"][seg]
            state["gain"][seg] = min(max(g + a * (ratio - g), 0.5), 2.0)


__all__ = ["DETECTORS", "Alarm", "MonitorParams", "MonitorRecord", "ProcessMonitor"]
