r"""Regenerative chatter: the tool/workpiece modes and the chip cut from the surface left.

The pieces any milling machine of :mod:`machine` needs to chatter, as numba kernels over
plain arrays and an explicit state:

- **the modes** (:class:`common.modes.ModalModel`): each an oscillator along a direction
  of the X-Y plane, advanced over a step :math:`\Delta t` by its exact discretisation with
  the force held (:func:`discretise`); the relative displacement tool minus workpiece is
  :math:`q = \sum_p u_p\eta_p` (workpiece modes with :math:`\eta` driven by :math:`F` and
  counted with the sign that makes them add, :mod:`common.modes`);
- **the surface memory**: a ring of past samples of the spindle angle :math:`\psi`, the
  tool centre :math:`C` (rigid path plus :math:`q`) and the rigid centre :math:`R` alone.
  The flute now at immersion :math:`\phi` meets the surface left by the flutes that
  passed the same angle before, :math:`m = 1..M` tooth pitches ago (found by the spindle
  angle, so a speed change is followed exactly). With :math:`v(\phi) = [\sin\phi,
  -\cos\phi]` and flute radii :math:`r_j` (runout),

  .. math::

      h_j(t) = v^T C(t) + r_j - \max_{m=1..M}\big(v^T C(t_m) + r_{j-m}\big), \qquad
      \psi(t_m) = \psi(t) - m\,2\pi/N

  the chip from the surface the last cutting flute left (seed003 (4) with the runout chip
  of Kline & DeVor taken ``M`` flutes back): a tool thrown out of the cut (:math:`h \le
  0`) cuts nothing and leaves the surface as it was, the next flute meets the older one;
- **the force**: the linear edge law of :mod:`machine.milling` per flute and axial layer,
  over the part of each step the flute spends inside the engagement window (entry and
  exit to a fraction of a step), at the step's midpoint (the modes' midpoint predicted
  from their velocity): the exponential midpoint rule, second order;
- **the forced twin**: the same modes driven by the chip of the rigid motion alone
  (:math:`C` replaced by :math:`R`): the vibration the cut would have without
  regeneration. The **non-forced vibration** is :math:`q - q_{twin}`; in a stable cut
  it dies out, in chatter it grows (docs/chatter.md's definitions);
- **the truth** over each spindle revolution: the amplitudes of the forced and the
  non-forced vibration, :math:`A = \sqrt{2(\sigma_x^2 + \sigma_y^2)}` (a sinusoid of
  amplitude :math:`A` along one axis has exactly this).

The force passed on to the machine (the spindle housing, hence the feed drives) by the
tool modes is :math:`F - \sum_{tool} u_p m_p\ddot\eta_p` (what does not accelerate the
modal masses); workpiece modes pass theirs to the table.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numba import njit

from common.arrays import F64
from common.linalg import zoh
from common.modes import ModalModel

#: rows of the per-step output vector of :func:`regen_substep`
SUB_ROWS = (
    "fx",
    "fy",
    "fx_forced",
    "fy_forced",
    "fx_base",
    "fy_base",
    "torque",
    "qx",
    "qy",
    "nfx",
    "nfy",
    "chip_max",
    "engaged",
    "in_cut",
)
#: truth accumulators: samples and sums of the non-forced and forced vibration over the
#: current revolution, then the revolution index and the last revolution's amplitudes
T_N, T_SX, T_SXX, T_SY, T_SYY, T_FX, T_FXX, T_FY, T_FYY, T_REV, T_ANF, T_AF = range(12)
TRUTH_LEN = 12
#: columns of the surface memory: spindle angle, tool centre (with q), rigid centre
#: and the synchronous means of q - q_twin over one tooth period, two tooth periods and
#: one revolution (see :func:`_synchronous_split`)
H_PSI, H_CX, H_CY, H_RX, H_RY, H_K1X, H_K1Y, H_K2X, H_K2Y, H_KRX, H_KRY = range(11)
H_COLS = 11
#: weight of the newest period in each synchronous mean (a memory of ~10 periods)
COMB_GAIN = 0.1


def discretise(modal: ModalModel, dt: float) -> F64:
    """Per-mode exact step with the force held: rows ``[p11, p12, p21, p22, g1, g2]`` with
    :math:`[\\eta, \\dot\\eta]^+ = P[\\eta, \\dot\\eta] + g\\,f/m`."""
    out = np.zeros((len(modal.modes), 6))
    for i, m in enumerate(modal.modes):
        w = m.omega
        a = np.array([[0.0, 1.0], [-w * w, -2.0 * m.damping * w]])
        p, g = zoh(a, np.array([[0.0], [1.0]]), dt)
        out[i] = (p[0, 0], p[0, 1], p[1, 0], p[1, 1], g[0, 0], g[1, 0])
    return out


def history_length(n_flutes: int, passes: int, rpm: float, dt: float) -> int:
    """Samples the surface memory needs to reach ``passes`` pitches back at ``rpm``."""
    back = passes * 60.0 / (n_flutes * rpm)
    return math.ceil(back / dt) + 8


@njit(cache=True)
def fill_history(
    hist: F64, hmeta: np.ndarray, dt: float, omega: float, feed: float, ecc: float, ecc_ph: float
) -> None:  # pragma: no cover
    """The past of a steady cut: straight feed along X at ``feed`` [m/s], spindle at
    ``omega`` [rad/s], the eccentric centre of seed003 (6), no vibration; the newest
    sample is t = 0 at ``psi = 0`` (the kernel's next sample)."""
    n = hist.shape[0]
    for i in range(n):
        t = -(n - i) * dt
        ps = omega * t
        rx = feed * t + ecc * math.cos(ps + ecc_ph)
        ry = ecc * math.sin(ps + ecc_ph)
        hist[i, H_PSI] = ps
        hist[i, H_CX] = rx
        hist[i, H_CY] = ry
        hist[i, H_RX] = rx
        hist[i, H_RY] = ry
        for c in range(H_K1X, H_COLS):
            hist[i, c] = 0.0
    hmeta[0] = 0  # head: where the next sample goes
    hmeta[1] = n  # count of valid samples


@njit(cache=True, inline="always")
def _hist_at(
    hist: F64, hmeta: np.ndarray, target: float, out: F64, row: int, c0: int = 1, ncol: int = 4
) -> None:  # pragma: no cover
    """Interpolate columns ``c0 .. c0+ncol-1`` of the memory linearly at spindle angle
    ``target`` into ``out[row]`` (by default ``[cx, cy, rx, ry]``); the oldest sample when
    the memory does not reach back."""
    n = hist.shape[0]
    head = hmeta[0]
    count = hmeta[1]
    newest = head - 1 if head > 0 else n - 1
    d = hist[newest, H_PSI] - hist[newest - 1 if newest > 0 else n - 1, H_PSI]
    j = 0
    if d > 0.0:
        j = int((hist[newest, H_PSI] - target) / d)
    j = max(0, min(j, count - 2))
    # bracket: psi(j + 1 back) <= target <= psi(j back)
    while j > 0 and hist[(newest - j) % n, H_PSI] < target:
        j -= 1
    while j < count - 2 and hist[(newest - j - 1) % n, H_PSI] > target:
        j += 1
    ia = (newest - j) % n
    ib = (newest - j - 1) % n
    span = hist[ia, H_PSI] - hist[ib, H_PSI]
    w = 0.0
    if span > 0.0:
        w = (target - hist[ib, H_PSI]) / span
        w = min(1.0, max(0.0, w))
    for c in range(ncol):
        out[row, c] = hist[ib, c0 + c] + w * (hist[ia, c0 + c] - hist[ib, c0 + c])


@njit(cache=True, inline="always")
def _window_part(
    a: float, b: float, st: float, ex: float
) -> tuple[float, float]:  # pragma: no cover
    """Fraction of ``[a, b]`` (``0 <= a``, ``b - a < pi``) inside the window ``[st, ex]``
    repeating every 2 pi, and the angle at the middle of that part."""
    two_pi = 2.0 * math.pi
    inside = 0.0
    mid = 0.0
    for shift in (0.0, two_pi):
        lo = max(a, st + shift)
        hi = min(b, ex + shift)
        if hi > lo:
            inside += hi - lo
            mid = 0.5 * (lo + hi)
    if b <= a:
        return 0.0, a
    return inside / (b - a), mid


class RegenCut(NamedTuple):
    """The cut and the structure as the regeneration kernels take them (read only)."""

    cutp: F64  # pack_cut: [N, phi_st, phi_ex, kt, kn, kte, kne, dz, R, M]
    lags: F64  # each axial layer's lag [rad] (helix)
    runout: F64  # each flute's radial runout [m]
    modes: F64  # ModalModel.packed()
    disc: F64  # discretise(): the modes' exact step over dt


class RegenMemory(NamedTuple):
    """What the cut carries from step to step (updated in place)."""

    eta: F64  # modal coordinates and velocities (actual)
    eta_f: F64  # the same of the forced twin
    hist: F64  # the surface memory (a ring, H_* columns)
    hmeta: np.ndarray  # [head, filled]
    truth: F64  # the truth accumulators (T_*)
    past: F64  # scratch: the centres 1..M pitches back, the comb filters' outputs


@njit(cache=True, inline="always")
def _chip_forces(
    psi0: float,
    psi1: float,
    cmx: float,
    cmy: float,
    rmx: float,
    rmy: float,
    cut: RegenCut,
    mem: RegenMemory,
    sub: F64,
) -> None:  # pragma: no cover
    """Forces on the tool over the step from ``psi0`` to ``psi1`` with the tool centre
    ``(cmx, cmy)`` and the rigid centre ``(rmx, rmy)`` at its midpoint; fills the force
    rows of ``sub``. The centres one to ``M`` pitches back are read from the memory into
    ``past`` when the first flute is found in the cut (not at all when none is)."""
    cutp, lags, runout = cut.cutp, cut.lags, cut.runout
    hist, hmeta, past = mem.hist, mem.hmeta, mem.past
    nf = int(cutp[0])
    st = cutp[1]
    ex = cutp[2]
    dz = cutp[7]
    rad = cutp[8]
    npass = int(cutp[9])
    pitch = 2.0 * math.pi / nf
    two_pi = 2.0 * math.pi
    fx = fy = gx = gy = torque = hmax = engaged = in_cut = 0.0
    looked = False
    for j in range(nf):
        for ll in range(lags.shape[0]):
            base = psi0 - j * pitch - lags[ll]
            a = base - two_pi * math.floor(base / two_pi)
            frac, phi = _window_part(a, a + (psi1 - psi0), st, ex)
            if frac <= 0.0:
                continue
            if not looked:
                psim = 0.5 * (psi0 + psi1)
                for m in range(npass):
                    _hist_at(hist, hmeta, psim - (m + 1) * pitch, past, m)
                looked = True
            s = math.sin(phi)
            c = math.cos(phi)
            # the surface: the highest edge reach of the flutes 1..M pitches back
            top = -1e300
            top_r = -1e300
            for m in range(npass):
                rj = runout[(j - m - 1) % nf]
                top = max(top, past[m, 0] * s - past[m, 1] * c + rj)
                top_r = max(top_r, past[m, 2] * s - past[m, 3] * c + rj)
            # seed003 (4) with the surface memory: h = v.C + r_j - max_m(v.C(t_m) + r_{j-m})
            h = cmx * s - cmy * c + runout[j] - top
            hn = rmx * s - rmy * c + runout[j] - top_r
            engaged += frac
            # the edge (rubbing) force follows the nominal engagement, not the vibrating
            # chip (a choice, the linear theory's: a force switched by the sign of h lets
            # nanometres of vibration switch tens of newtons at an up-milling entry, where
            # h grows from 0; the simulator then chattered at 0.72x the lobes' depth)
            e = 0.0
            if hn > 0.0:
                e = dz * frac
                gx -= (cutp[3] * hn * dz * frac + cutp[5] * e) * c + (
                    cutp[4] * hn * dz * frac + cutp[6] * e
                ) * s
                gy -= (cutp[3] * hn * dz * frac + cutp[5] * e) * s - (
                    cutp[4] * hn * dz * frac + cutp[6] * e
                ) * c
            ft = cutp[5] * e
            fr = cutp[6] * e
            if h > 0.0:
                ft += cutp[3] * h * dz * frac
                fr += cutp[4] * h * dz * frac
                hmax = max(hmax, h)
                in_cut += frac
            # force on the tool: -(ft along the edge velocity [c, s] + fr along v)
            fx -= ft * c + fr * s
            fy -= ft * s - fr * c
            torque += ft * rad
    sub[0] = fx
    sub[1] = fy
    sub[2] = gx
    sub[3] = gy
    sub[6] = torque
    sub[11] = hmax
    sub[12] = engaged
    sub[13] = in_cut


@njit(cache=True, inline="always")
def _modal_advance(
    eta: F64, modes: F64, disc: F64, fx: float, fy: float
) -> tuple[float, float]:  # pragma: no cover
    """Advance every mode one step under the force ``(fx, fy)`` held; returns ``q``."""
    qx = 0.0
    qy = 0.0
    for p in range(modes.shape[0]):
        f = (modes[p, 3] * fx + modes[p, 4] * fy) / modes[p, 2]
        e0 = eta[p, 0]
        e1 = eta[p, 1]
        eta[p, 0] = disc[p, 0] * e0 + disc[p, 1] * e1 + disc[p, 4] * f
        eta[p, 1] = disc[p, 2] * e0 + disc[p, 3] * e1 + disc[p, 5] * f
        qx += modes[p, 3] * eta[p, 0]
        qy += modes[p, 4] * eta[p, 0]
    return qx, qy


@njit(cache=True, inline="always")
def _modal_q(eta: F64, modes: F64, half_dt: float) -> tuple[float, float]:  # pragma: no cover
    """``q`` a time ``half_dt`` ahead, predicted from each mode's velocity."""
    qx = 0.0
    qy = 0.0
    for p in range(modes.shape[0]):
        e = eta[p, 0] + half_dt * eta[p, 1]
        qx += modes[p, 3] * e
        qy += modes[p, 4] * e
    return qx, qy


@njit(cache=True, inline="always")
def _base_force(
    eta: F64, modes: F64, fx: float, fy: float
) -> tuple[float, float]:  # pragma: no cover
    """Force passed to the spindle housing: ``F`` minus what accelerates the tool modes."""
    bx = fx
    by = fy
    for p in range(modes.shape[0]):
        if modes[p, 5] == 0.0:
            continue
        w = modes[p, 0]
        ux = modes[p, 3]
        uy = modes[p, 4]
        # m eta'' = u.F - k eta - c eta'
        mdd = ux * fx + uy * fy - modes[p, 2] * w * (w * eta[p, 0] + 2.0 * modes[p, 1] * eta[p, 1])
        bx -= ux * mdd
        by -= uy * mdd
    return bx, by


@njit(cache=True, inline="always")
def _truth_update(
    truth: F64, psi1: float, nfx: float, nfy: float, qfx: float, qfy: float
) -> None:  # pragma: no cover
    """Accumulate one sample; at a new revolution of ``psi1`` close the amplitudes."""
    rev = math.floor(psi1 / (2.0 * math.pi))
    if rev > truth[T_REV] and truth[T_N] > 1.0:
        n = truth[T_N]
        vx = truth[T_SXX] / n - (truth[T_SX] / n) ** 2
        vy = truth[T_SYY] / n - (truth[T_SY] / n) ** 2
        truth[T_ANF] = math.sqrt(2.0 * max(vx + vy, 0.0))
        vx = truth[T_FXX] / n - (truth[T_FX] / n) ** 2
        vy = truth[T_FYY] / n - (truth[T_FY] / n) ** 2
        truth[T_AF] = math.sqrt(2.0 * max(vx + vy, 0.0))
        for i in range(T_REV):
            truth[i] = 0.0
    truth[T_REV] = rev
    truth[T_N] += 1.0
    truth[T_SX] += nfx
    truth[T_SXX] += nfx * nfx
    truth[T_SY] += nfy
    truth[T_SYY] += nfy * nfy
    truth[T_FX] += qfx
    truth[T_FXX] += qfx * qfx
    truth[T_FY] += qfy
    truth[T_FYY] += qfy * qfy


@njit(cache=True, inline="always")
def _synchronous_split(
    hist: F64, hmeta: np.ndarray, psi1: float, n_flutes: float, dx: float, dy: float, past: F64
) -> tuple[float, float]:  # pragma: no cover
    """The non-forced part of ``d = q - q_twin`` at spindle angle ``psi1``; the updated
    synchronous means go to ``past[1:4]`` (tooth, two teeth, revolution) for the memory.

    The twin leaves out what the forced vibration itself does to the cut: where it
    clips a thin chip (an up-milling entry) and how the cut regenerates the runout's
    vibration. Both repeat with the revolution, so the revolution-synchronous mean of
    ``d`` (an exponential mean over revolutions at the same spindle angle) is forced too.
    Chatter does not repeat with the revolution (Hopf: a new frequency), except period
    doubling with an even flute count: it lies at (k + 1/2) tooth frequency, a spindle
    harmonic, and alternates sign every tooth, so it is the two-tooth mean minus the
    one-tooth mean, given back to the non-forced part (docs/chatter.md, "Definitions").
    """
    pitch = 2.0 * math.pi / n_flutes
    for r, back in ((1, pitch), (2, 2.0 * pitch), (3, 2.0 * math.pi)):
        _hist_at(hist, hmeta, psi1 - back, past, r, H_K1X + 2 * (r - 1), 2)
        past[r, 0] += COMB_GAIN * (dx - past[r, 0])
        past[r, 1] += COMB_GAIN * (dy - past[r, 1])
    nfx = dx - past[3, 0]
    nfy = dy - past[3, 1]
    if int(n_flutes) % 2 == 0:
        nfx += past[2, 0] - past[1, 0]
        nfy += past[2, 1] - past[1, 1]
    return nfx, nfy


@njit(cache=True, inline="always")
def regen_substep(
    psi0: float,
    psi1: float,
    r0x: float,
    r0y: float,
    r1x: float,
    r1y: float,
    dt: float,
    cut: RegenCut,
    mem: RegenMemory,
    sub: F64,
) -> None:  # pragma: no cover
    """One step of the cut from ``psi0`` to ``psi1`` with the rigid centre moving from
    ``r0`` to ``r1``: chip, force, modes (actual and forced twin), memory, truth.

    ``sub`` receives the step's outputs (:data:`SUB_ROWS`): the forces are the step's
    (held over it), ``q`` and the non-forced vibration those at its end.
    """
    cutp, modes, disc = cut.cutp, cut.modes, cut.disc
    eta, eta_f, hist, hmeta, truth, past = (
        mem.eta,
        mem.eta_f,
        mem.hist,
        mem.hmeta,
        mem.truth,
        mem.past,
    )
    half = 0.5 * dt
    # midpoint: rigid centre interpolated, modes predicted from their velocity
    rmx = 0.5 * (r0x + r1x)
    rmy = 0.5 * (r0y + r1y)
    qx, qy = _modal_q(eta, modes, half)
    _chip_forces(psi0, psi1, rmx + qx, rmy + qy, rmx, rmy, cut, mem, sub)
    bx, by = _base_force(eta, modes, sub[0], sub[1])
    sub[4] = bx
    sub[5] = by
    qx, qy = _modal_advance(eta, modes, disc, sub[0], sub[1])
    fx, fy = _modal_advance(eta_f, modes, disc, sub[2], sub[3])
    nfx, nfy = _synchronous_split(hist, hmeta, psi1, cutp[0], qx - fx, qy - fy, past)
    sub[7] = qx
    sub[8] = qy
    sub[9] = nfx
    sub[10] = nfy
    n = hist.shape[0]
    head = hmeta[0]
    hist[head, H_PSI] = psi1
    hist[head, H_CX] = r1x + qx
    hist[head, H_CY] = r1y + qy
    hist[head, H_RX] = r1x
    hist[head, H_RY] = r1y
    for c in range(6):
        hist[head, H_K1X + c] = past[1 + c // 2, c % 2]
    hmeta[0] = (head + 1) % n
    hmeta[1] = min(hmeta[1] + 1, n)
    _truth_update(truth, psi1, nfx, nfy, qx - nfx, qy - nfy)


def pack_cut(
    n_flutes: int,
    window: tuple[float, float],
    coeffs: tuple[float, float, float, float],
    layer_depth: float,
    radius: float,
    passes: int,
) -> F64:
    """The kernel's cut vector: ``[N, phi_st, phi_ex, kt, kn, kte, kne, dz, R, M]``."""
    return np.array(
        [float(n_flutes), window[0], window[1], *coeffs, layer_depth, radius, float(passes)]
    )


def new_truth() -> F64:
    """Fresh truth accumulators (no revolution closed yet)."""
    t = np.zeros(TRUTH_LEN)
    t[T_REV] = -1.0
    return t


def grow_history(hist: F64, hmeta: np.ndarray, need: int) -> tuple[F64, np.ndarray]:
    """The memory unrolled (oldest first) into a longer ring, the old past kept."""
    n = hist.shape[0]
    head = int(hmeta[0])
    order = np.concatenate([np.arange(head, n), np.arange(0, head)])
    new = np.empty((need, hist.shape[1]))
    # pad the far past with the oldest sample (it is never reached: too far back)
    new[: need - n] = hist[order[0]]
    new[need - n :] = hist[order]
    return new, np.array([0, need], dtype=np.int64)


@dataclass
class ChatterTruth:
    """Onset, development, amplitude and frequency of chatter, from the truth rows."""

    onset_t: float | None = None
    developed_t: float | None = None
    amp_nonforced: float = 0.0
    amp_forced: float = 0.0
    _buf: list[F64] = field(default_factory=list)
    _bt: list[F64] = field(default_factory=list)

    def update(self, t: F64, anf: F64, af: F64, nfx: F64, nfy: F64) -> None:
        if t.size == 0:
            return
        cutting = af > 0.0
        if self.onset_t is None:
            hit = np.flatnonzero(cutting & (anf > 0.1 * af))
            self.onset_t = float(t[hit[0]]) if hit.size else None
        if self.developed_t is None:
            hit = np.flatnonzero(cutting & (anf >= af))
            self.developed_t = float(t[hit[0]]) if hit.size else None
        self.amp_nonforced = float(anf[-1])
        self.amp_forced = float(af[-1])
        self._buf.append(np.stack([nfx, nfy]))
        self._bt.append(t)
        while sum(b.shape[1] for b in self._buf) > 2 * FREQ_WINDOW and len(self._buf) > 1:
            self._buf.pop(0)
            self._bt.pop(0)

    def frequency(self) -> float:
        """The largest spectral peak [Hz] of the last :data:`FREQ_WINDOW` samples of the
        non-forced vibration (both axes), refined by a parabola through its neighbours."""
        if not self._buf:
            return math.nan
        x = np.concatenate(self._buf, axis=1)[:, -FREQ_WINDOW:]
        t = np.concatenate(self._bt)[-FREQ_WINDOW:]
        return dominant_frequency(x, float(np.median(np.diff(t))) if t.size > 1 else 1.0)


#: samples of the non-forced vibration the frequency is taken from
FREQ_WINDOW = 8192


def dominant_frequency(x: F64, dt: float) -> float:
    """The largest spectral peak [Hz] of the rows of ``x`` (summed power, Hann window),
    refined by a parabola through the log power of its neighbours."""
    n = x.shape[-1]
    if n < 8:
        return math.nan
    w = np.hanning(n)
    p = np.sum(np.abs(np.fft.rfft((x - x.mean(axis=-1, keepdims=True)) * w, axis=-1)) ** 2, axis=0)
    p[0] = 0.0
    i = int(np.argmax(p))
    if 0 < i < p.size - 1 and np.all(p[i - 1 : i + 2] > 0):
        a, b, c = np.log(p[i - 1 : i + 2])
        den = a - 2 * b + c
        i_f = i + (0.5 * (a - c) / den if den != 0 else 0.0)
    else:
        i_f = float(i)
    return float(i_f / (n * dt))


__all__ = [
    "FREQ_WINDOW",
    "SUB_ROWS",
    "TRUTH_LEN",
    "ChatterTruth",
    "RegenCut",
    "RegenMemory",
    "discretise",
    "dominant_frequency",
    "fill_history",
    "grow_history",
    "history_length",
    "new_truth",
    "pack_cut",
    "regen_substep",
]
