r"""The machining centre's per-sample loop: one numba kernel over a block of samples.

Every sample, in this order (all evaluated on the state at sample *k*, then every state
advances to *k + 1*):

1. **Interpolator**: the path parameter of the running program block (speed toward the
   programmed feed times the override, the acceleration limit, braking to an exact stop
   at the block's end); the commanded position, velocity and acceleration per axis, with
   seed003 (7)'s modulation circle on X and Y when one is set (an eccentricity
   canceller's output).
2. **Cut**: the tool centre relative to the workpiece (the axes' *load* positions plus
   the runout, seed003 (6)); the chip of every flute and axial layer from the surfaces
   the previous two flutes left (seed003 (1)-(5), the runout chip of
   :mod:`machine.process`), with the immersion window turned to the feed direction; the
   force on the workpiece (X, Y and the axial Z) and the cutting torque on the spindle.
   **Chatter plugs in here** (issue 29): :func:`_structure` advances the tool/workpiece
   structure (its parameters ``sp_struct``, its state ``st_struct``, packed by the
   caller) under the previous sample's force and returns its displacement, which is
   added to the tool centre before the chip is taken; the chip history already holds
   the surfaces regeneration needs. Today the structure is rigid (empty arrays: no
   displacement).
3. **Spindle**: speed command ramped, PI speed loop on the filtered measured speed with
   the torque and power limits (integration held while limited), the current loop as a
   first-order lag after one sample of computation, the rotor under the motor, friction
   and cutting torques (exact for the viscous part), the CNC's power (torque times
   measured speed, smoothed).
4. **Feed axes**: encoder (and, on X, linear scale) quantised; speed actual value from the
   encoder's difference, filtered; position P loop (+ velocity feed-forward) on the scale
   (X) or the encoder (Y, Z); PI speed loop (+ acceleration feed-forward); force limit;
   current loop as for the spindle; the mechanics advanced by their exact zero-order-hold
   matrices (two inertias on X; one mass on Y and Z, simulated as two equal copies so one
   code path serves both), Coulomb friction (tanh-smoothed) and the process force and
   weight on the load side held over the sample.

The packed parameter and state arrays are read through the index constants below;
:mod:`machine.centre.sim` builds them. Signals written per sample: :data:`ROWS`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from common.arrays import F64

# --- per-axis parameters (axp[i, AP_*]) -----------------------------------------------
AP_KV, AP_KP, AP_KI, AP_MFF, AP_BI, AP_BF, AP_FMAX, AP_KF = 0, 1, 2, 3, 4, 5, 6, 7
AP_QM, AP_QL, AP_FCM, AP_FCL, AP_GRAV, AP_NOISE, AP_LSB, AP_VS, AP_SCALE = (
    8, 9, 10, 11, 12, 13, 14, 15, 16,
)  # fmt: skip
N_AP = 17
# --- per-axis state (ax[i, AX_*]): plant [x_m, v_m, x_l, v_l], then the drive ----------
AX_XM, AX_VM, AX_XL, AX_VL, AX_FA, AX_VF, AX_INT, AX_QPREV = 0, 1, 2, 3, 4, 5, 6, 7
N_AX = 8
# --- spindle parameters (spp[SP_*]) -----------------------------------------------------
SP_KP, SP_KI, SP_BI, SP_BF, SP_E1, SP_E2, SP_TMAX, SP_PMAX = 0, 1, 2, 3, 4, 5, 6, 7
SP_TC, SP_WSHARE, SP_WTIME, SP_RAMP, SP_KT, SP_NOISE, SP_BP, SP_WS = (
    8, 9, 10, 11, 12, 13, 14, 15,
)  # fmt: skip
N_SP = 16
# --- spindle state (ss[SS_*]) ---------------------------------------------------------
SS_W, SS_PSI, SS_TA, SS_WF, SS_INT, SS_WREF, SS_P, SS_RUN = 0, 1, 2, 3, 4, 5, 6, 7
N_SS = 8
# --- the running program block (pp[PP_*]) ---------------------------------------------
PP_P0, PP_U = 0, 3  # start point (3), unit direction (3)
PP_L, PP_V, PP_ACC, PP_KIND, PP_SECONDS, PP_RPM = 6, 7, 8, 9, 10, 11
N_PP = 12
#: block kinds of the kernel (PP_KIND)
K_MOVE, K_DWELL, K_SPINDLE = 0, 1, 2
# --- interpolator state (ps[PS_*]) ----------------------------------------------------
PS_S, PS_V, PS_T, PS_K, PS_DONE, PS_OVR, PS_SOVR, PS_AM, PS_THM = 0, 1, 2, 3, 4, 5, 6, 7, 8
N_PS = 9
# --- the cut of the running block (cp[CP_*]) ------------------------------------------
CP_ACTIVE, CP_DZ, CP_PHI_ST, CP_PHI_EX, CP_BETA, CP_RAMP, CP_RAMP_IN, CP_RAMP_OUT = (
    0, 1, 2, 3, 4, 5, 6, 7,
)  # fmt: skip
CP_NF, CP_KTC, CP_KRC, CP_KTE, CP_KRE, CP_KAC, CP_KAE = 8, 9, 10, 11, 12, 13, 14
CP_ECC, CP_ECC_PH, CP_RADIUS, CP_K_EV, CP_FEED_MUL, CP_LOST, CP_LOST_AFTER, CP_HEAD = (
    15, 16, 17, 18, 19, 20, 21, 22,
)  # fmt: skip
N_CP = 23

# --- per-sample output rows -------------------------------------------------------------
#: per axis (base 7 i): commanded position [m], motor encoder [m], linear scale [m] (the
#: encoder on a rigid axis), speed actual value [m/s], motor current [A]; truth: process
#: force on the workpiece along the axis [N], the load's true position [m]
AXIS_ROWS = ("q_cmd", "q_m", "q_l", "qd_m", "i_m", "f_process", "x_load")
R_AXIS = len(AXIS_ROWS)
#: spindle: speed actual value [rpm], current [A], the CNC's power [W], commanded speed
#: [rpm]; truth: cutting torque [N m], true speed [rpm], angle [rad]
SPINDLE_ROWS = ("speed", "current", "power", "speed_cmd", "torque_cut", "speed_true", "psi")
R_SPINDLE = 3 * R_AXIS
R_ENGAGED = R_SPINDLE + len(SPINDLE_ROWS)
ROWS = (
    *(f"{a}.{r}" for a in "XYZ" for r in AXIS_ROWS),
    *(f"S.{r}" for r in SPINDLE_ROWS),
    "engaged",
)
N_ROWS = len(ROWS)


class AxisCommand(NamedTuple):
    """The interpolator's command to one feed axis for one sample. Scalars only: the
    record of arrays (:class:`CentreDesign`) handed to :func:`_axis` three times a sample
    made the machine's step 1.3x slower (its arrays' reference counts); it is unpacked
    once per call of :func:`step_block` instead."""

    r: float  # position [m]
    vff: float  # velocity feed-forward [m/s]
    aff: float  # acceleration feed-forward [m/s^2]


class CentreDesign(NamedTuple):
    """The machine as :func:`step_block` takes it (read only; made per call)."""

    ts: float  # sample time [s]
    axp: F64  # (3, N_AP) per-axis parameters, AP_*
    phi: F64  # (3, 4, 4) each axis's mechanics over one sample, exp(A ts)
    gam: F64  # (3, 4, 2) its inputs (motor force, load force) held over the sample
    spp: F64  # (N_SP,) spindle parameters, SP_*
    sp_struct: F64  # the tool/workpiece structure's parameters (empty: rigid)


class CentreBlock(NamedTuple):
    """The running program block as :func:`step_block` takes it (``cp[CP_HEAD]`` is
    written back: the chip history's head)."""

    pp: F64  # (N_PP,) the path, PP_*
    cp: F64  # (N_CP,) the cut, CP_*
    lags: F64  # the helix lag of each axial layer [rad]
    dr0: F64  # (MAX_FLUTES,) the radius each flute has lost [m], before the block's event
    dr1: F64  # and after it (a breakage)


class CentreArrays(NamedTuple):
    """The machine's state as :func:`step_block` updates it (in place)."""

    ax: F64  # (3, N_AX) per-axis state, AX_*
    ss: F64  # (N_SS,) spindle state, SS_*
    ps: F64  # (N_PS,) interpolator state, PS_*
    hist: F64  # (n, 2) the surfaces the previous flutes left (the chip history)
    st_struct: F64  # the tool/workpiece structure's state (empty: rigid)


@njit(cache=True)
def _interpolate(
    pp: F64, ps: F64, cp: F64, after: bool, ts: float, r: F64, vff: F64, aff: F64
) -> None:  # pragma: no cover
    """Advance the path one sample (``ps`` in place); the commands into ``r, vff, aff``."""
    s = ps[PS_S]
    v = ps[PS_V]
    kind = pp[PP_KIND]
    v_new = 0.0
    if kind == K_MOVE and ps[PS_DONE] == 0.0:
        length = pp[PP_L]
        acc = pp[PP_ACC]
        if after and cp[CP_FEED_MUL] != 1.0:
            # a collision: driven on at a multiple of the feed at once, no braking
            v_new = pp[PP_V] * cp[CP_FEED_MUL]
        else:
            # braking to an exact stop: the speed from which the distance left after this
            # sample still suffices to stop, v ts + v^2 / (2 a) <= L - s
            at = acc * ts
            v_brake = -at + math.sqrt(at * at + 2.0 * acc * max(length - s, 0.0))
            vt = min(pp[PP_V] * ps[PS_OVR], v_brake)
            v_new = min(vt, v + acc * ts) if v < vt else max(vt, v - acc * ts)
        if length - s <= v_new * ts or length - s <= 1e-12:
            v_new = (length - s) / ts
            s = length
            ps[PS_DONE] = 1.0
        else:
            s += v_new * ts
    a = (v_new - v) / ts
    for i in range(3):
        r[i] = pp[PP_P0 + i] + s * pp[PP_U + i]
        vff[i] = v_new * pp[PP_U + i]
        aff[i] = a * pp[PP_U + i]
    ps[PS_S] = s
    ps[PS_V] = v_new
    ps[PS_T] += ts
    ps[PS_K] += 1.0


@njit(cache=True)
def _modulate(
    ps: F64, psi: float, w: float, r: F64, vff: F64, aff: F64
) -> None:  # pragma: no cover
    """seed003 (7): the circle ``a_m [cos(psi + theta_m), sin(psi + theta_m)]`` added to
    the X and Y commands (with its velocity and acceleration for the feed-forward), the
    spindle angle from its encoder (the true angle: the encoder's resolution is far below
    what matters here)."""
    a = ps[PS_AM]
    if a == 0.0:
        return
    c = math.cos(psi + ps[PS_THM])
    s = math.sin(psi + ps[PS_THM])
    r[0] += a * c
    r[1] += a * s
    vff[0] -= a * w * s
    vff[1] += a * w * c
    aff[0] -= a * w * w * c
    aff[1] -= a * w * w * s


@njit(cache=True)
def _engagement(pp: F64, cp: F64, after: bool, xl: float, yl: float) -> float:  # pragma: no cover
    """Share of the cut's axial depth engaged: the stock under the block's path, ramped
    over one tool radius at the ends (:mod:`machine.centre.program`), less what the tool
    has lost."""
    if cp[CP_ACTIVE] == 0.0:
        return 0.0
    s = (xl - pp[PP_P0]) * pp[PP_U] + (yl - pp[PP_P0 + 1]) * pp[PP_U + 1]
    ramp = cp[CP_RAMP]
    e = 1.0
    if cp[CP_RAMP_IN] != 0.0:
        e = min(max(s / ramp, 0.0), 1.0)
    collided = after and cp[CP_FEED_MUL] != 1.0
    if cp[CP_RAMP_OUT] != 0.0 and not collided:
        e = min(e, min(max((pp[PP_L] - s) / ramp, 0.0), 1.0))
    e *= 1.0 - cp[CP_LOST]
    if after:
        e *= 1.0 - cp[CP_LOST_AFTER]
    return e


@njit(cache=True)
def _structure(
    sp_struct: F64, st_struct: F64, fx: float, fy: float, ts: float
) -> tuple[float, float]:  # pragma: no cover
    """The tool's displacement relative to the workpiece from their structure under the
    force on the workpiece ``(fx, fy)`` of the previous sample (issue 29's plug: its
    modes advance ``st_struct`` here). Today rigid: no displacement."""
    return 0.0, 0.0


@njit(cache=True)
def _cut(
    psi: float, omega: float, px: float, py: float, e: float, cp: F64, lags: F64,
    dr: F64, hist: F64, ts: float, f: F64,
) -> None:  # pragma: no cover  # fmt: skip
    """Force on the workpiece ``f[0:3]`` [N] and cutting torque ``f[3]`` [N m] (seed003
    (1)-(5) per flute and layer, the runout chip over the last two flutes)."""
    hlen = hist.shape[0]
    head = int(cp[CP_HEAD])
    hist[head, 0] = px
    hist[head, 1] = py
    cp[CP_HEAD] = (head + 1) % hlen
    f[0] = 0.0
    f[1] = 0.0
    f[2] = 0.0
    f[3] = 0.0
    if e <= 0.0 or omega <= 1.0:
        return
    nf = int(cp[CP_NF])
    two_pi = 2.0 * math.pi
    pitch = two_pi / nf
    lag1 = min(pitch / omega / ts, 0.5 * (hlen - 3))
    d1x = d1y = d2x = d2y = 0.0
    for m in range(1, 3):
        back = m * lag1
        i0 = math.floor(back)
        fr = back - i0
        ia = (head - i0) % hlen
        ib = (head - i0 - 1) % hlen
        qx = (1.0 - fr) * hist[ia, 0] + fr * hist[ib, 0]
        qy = (1.0 - fr) * hist[ia, 1] + fr * hist[ib, 1]
        if m == 1:
            d1x, d1y = px - qx, py - qy
        else:
            d2x, d2y = px - qx, py - qy
    dze = cp[CP_DZ] * e
    beta = cp[CP_BETA]
    phi_st = cp[CP_PHI_ST]
    phi_ex = cp[CP_PHI_EX]
    for j in range(nf):
        jm1 = (j - 1) % nf
        jm2 = (j - 2) % nf
        # the flute's angle from the feed direction beta, in [0, 2 pi)
        rel0 = (psi - j * pitch - beta) % two_pi
        for li in range(lags.shape[0]):
            # seed003 (5): the window, measured from the feed direction (layer lags
            # are in [0, 2 pi): one turn back at most)
            rel = rel0 - lags[li]
            if rel < 0.0:
                rel += two_pi
            if rel < phi_st or rel > phi_ex:
                continue
            # seed003 (1): immersion of flute j, layer l (absolute angle)
            phi = psi - j * pitch - lags[li]
            s = math.sin(phi)
            c = math.cos(phi)
            # seed003 (4), the runout chip: h = min over m of dP(m tau).n(phi) + r_j - r_{j-m}
            h1 = d1x * s - d1y * c + dr[j] - dr[jm1]
            h2 = d2x * s - d2y * c + dr[j] - dr[jm2]
            h = min(h1, h2)
            if h <= 0.0:
                continue
            ft = (cp[CP_KTC] * h + cp[CP_KTE]) * dze
            fr_ = (cp[CP_KRC] * h + cp[CP_KRE]) * dze
            f[0] += ft * c + fr_ * s
            f[1] += ft * s - fr_ * c
            f[2] += (cp[CP_KAC] * h + cp[CP_KAE]) * dze
            f[3] += ft
    f[3] *= cp[CP_RADIUS]


@njit(cache=True)
def _spindle(
    spp: F64, ss: F64, rpm_cmd: float, t_cut: float, ts: float, noise: float
) -> float:  # pragma: no cover
    """One sample of the spindle drive (``ss`` in place); returns the measured current."""
    w = ss[SS_W]
    # the speed command, ramped
    target = rpm_cmd * math.pi / 30.0
    step = spp[SP_RAMP] * ts
    wref = ss[SS_WREF]
    wref = min(target, wref + step) if wref < target else max(target, wref - step)
    ss[SS_WREF] = wref
    # speed actual value: the encoder's speed through a first-order filter
    ss[SS_WF] += spp[SP_BF] * (w - ss[SS_WF])
    wf = ss[SS_WF]
    e = wref - wf
    t_set = spp[SP_KP] * e + ss[SS_INT]
    t_lim = min(spp[SP_TMAX], spp[SP_PMAX] / max(abs(wf), 1e-6))
    limited = abs(t_set) > t_lim
    t_set = max(-t_lim, min(t_lim, t_set))
    if not limited:
        ss[SS_INT] += spp[SP_KI] * ts * e
    # the torque acting over this sample (the current loop one sample behind), then its lag
    ta = ss[SS_TA]
    ss[SS_TA] = ta + spp[SP_BI] * (t_set - ta)
    tc = spp[SP_TC] * (1.0 + spp[SP_WSHARE] * math.exp(-ss[SS_RUN] / spp[SP_WTIME]))
    fric = tc * math.tanh(w / spp[SP_WS])
    # rotor: J dw/dt = T_m - b w - T_c - T_cut, exact for the viscous part over the sample
    w_new = spp[SP_E1] * w + spp[SP_E2] * (ta - fric - t_cut)
    ss[SS_PSI] += 0.5 * (w + w_new) * ts
    ss[SS_W] = w_new
    if abs(w) > 1.0:
        ss[SS_RUN] += ts
    # the CNC's power: torque times measured speed, smoothed
    ss[SS_P] += spp[SP_BP] * (ta * wf - ss[SS_P])
    return ta / spp[SP_KT] + spp[SP_NOISE] * noise


@njit(cache=True)
def _axis(
    i: int, axp: F64, phi: F64, gam: F64, ax: F64, cmd: AxisCommand, f_work: float,
    ts: float, noise: float, out: F64, k: int,
) -> None:  # pragma: no cover  # fmt: skip
    """One sample of feed axis ``i`` (``ax[i]`` in place) under the interpolator's
    command ``cmd``; writes its rows of ``out``."""
    r, vff, aff = cmd.r, cmd.vff, cmd.aff
    p = axp[i]
    st = ax[i]
    qm = math.floor(st[AX_XM] / p[AP_QM]) * p[AP_QM]
    ql = math.floor(st[AX_XL] / p[AP_QL]) * p[AP_QL] if p[AP_SCALE] != 0.0 else qm
    v_raw = (qm - st[AX_QPREV]) / ts
    st[AX_QPREV] = qm
    st[AX_VF] += p[AP_BF] * (v_raw - st[AX_VF])
    # position loop on the scale (X) or the encoder, velocity feed-forward
    v_set = p[AP_KV] * (r - ql) + vff
    e = v_set - st[AX_VF]
    f_set = p[AP_KP] * e + st[AX_INT] + p[AP_MFF] * aff
    limited = abs(f_set) > p[AP_FMAX]
    f_set = max(-p[AP_FMAX], min(p[AP_FMAX], f_set))
    if not limited:
        st[AX_INT] += p[AP_KI] * ts * e
    fa = st[AX_FA]
    st[AX_FA] = fa + p[AP_BI] * (f_set - fa)
    # inputs held over the sample: motor side, load side (friction, process, weight)
    um = fa - p[AP_FCM] * math.tanh(st[AX_VM] / p[AP_VS])
    ul = -p[AP_FCL] * math.tanh(st[AX_VL] / p[AP_VS]) - f_work - p[AP_GRAV]
    x0, x1, x2, x3 = st[AX_XM], st[AX_VM], st[AX_XL], st[AX_VL]
    for row in range(4):
        st[row] = (
            phi[i, row, 0] * x0 + phi[i, row, 1] * x1 + phi[i, row, 2] * x2
            + phi[i, row, 3] * x3 + gam[i, row, 0] * um + gam[i, row, 1] * ul
        )  # fmt: skip
    i_meas = fa / p[AP_KF] + p[AP_NOISE] * noise
    if p[AP_LSB] > 0.0:
        i_meas = math.floor(i_meas / p[AP_LSB] + 0.5) * p[AP_LSB]
    b = R_AXIS * i
    out[b + 0, k] = r
    out[b + 1, k] = qm
    out[b + 2, k] = ql
    out[b + 3, k] = st[AX_VF]
    out[b + 4, k] = i_meas
    out[b + 5, k] = f_work
    out[b + 6, k] = x2


@njit(cache=True)
def step_block(
    n: int, k0: int, m: CentreDesign, blk: CentreBlock, s: CentreArrays, noise: F64, out: F64
) -> int:  # pragma: no cover
    """Advance the machine ``m`` (:class:`CentreDesign`) in state ``s``
    (:class:`CentreArrays`, in place) up to ``n`` samples within the program block ``blk``
    (:class:`CentreBlock`), writing columns ``k0, k0 + 1, ...`` of ``out``; stops early
    when the block is done. Returns the samples run. ``noise`` holds standard normals:
    rows X, Y, Z, spindle current."""
    ts, axp, phi, gam, spp, sp_struct = m.ts, m.axp, m.phi, m.gam, m.spp, m.sp_struct
    pp, cp, lags, dr0, dr1 = blk.pp, blk.cp, blk.lags, blk.dr0, blk.dr1
    ax, ss, ps, hist, st_struct = s.ax, s.ss, s.ps, s.hist, s.st_struct
    ra = np.zeros(3)
    va = np.zeros(3)
    aa = np.zeros(3)
    f = np.zeros(4)
    used = 0
    for k in range(k0, k0 + n):
        if ps[PS_DONE] != 0.0:
            break
        after = ps[PS_K] >= cp[CP_K_EV]
        _interpolate(pp, ps, cp, after, ts, ra, va, aa)
        _modulate(ps, ss[SS_PSI], ss[SS_W], ra, va, aa)
        psi = ss[SS_PSI]
        ecc = cp[CP_ECC]
        xl = ax[0, AX_XL]
        yl = ax[1, AX_XL]
        dx, dy = _structure(sp_struct, st_struct, f[0], f[1], ts)
        # seed003 (6): tool centre = the axes' load positions + the runout
        px = xl + dx + ecc * math.cos(psi + cp[CP_ECC_PH])
        py = yl + dy + ecc * math.sin(psi + cp[CP_ECC_PH])
        e = _engagement(pp, cp, after, xl, yl)
        dr = dr1 if after else dr0
        _cut(psi, ss[SS_W], px, py, e, cp, lags, dr, hist, ts, f)
        w_before = ss[SS_W]
        i_sp = _spindle(spp, ss, pp[PP_RPM] * ps[PS_SOVR], f[3], ts, noise[3, k])
        for i in range(3):
            cmd = AxisCommand(ra[i], va[i], aa[i])
            _axis(i, axp, phi, gam, ax, cmd, f[i], ts, noise[i, k], out, k)
        b = R_SPINDLE
        out[b + 0, k] = ss[SS_WF] * 30.0 / math.pi
        out[b + 1, k] = i_sp
        out[b + 2, k] = ss[SS_P]
        out[b + 3, k] = pp[PP_RPM] * ps[PS_SOVR]
        out[b + 4, k] = f[3]
        out[b + 5, k] = w_before * 30.0 / math.pi
        out[b + 6, k] = psi
        out[R_ENGAGED, k] = e
        _block_end(pp, ps, ss, ts)
        used += 1
    return used


@njit(cache=True)
def _block_end(pp: F64, ps: F64, ss: F64, ts: float) -> None:  # pragma: no cover
    """Mark a dwell, tool change or spindle block done when its condition holds."""
    kind = pp[PP_KIND]
    if kind == K_MOVE:
        return
    if ps[PS_T] + 0.5 * ts < pp[PP_SECONDS]:
        return
    if kind == K_SPINDLE:
        target = abs(pp[PP_RPM] * ps[PS_SOVR]) * math.pi / 30.0
        if abs(ss[SS_WF] - target) > 0.01 * max(target, 1.0):
            return
    ps[PS_DONE] = 1.0


__all__ = [
    "AXIS_ROWS",
    "N_ROWS",
    "ROWS",
    "SPINDLE_ROWS",
    "CentreArrays",
    "CentreBlock",
    "CentreDesign",
    "step_block",
]
