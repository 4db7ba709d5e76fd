r"""Seed 003's milling machine with a flexible tool: regeneration on the feed drives.

:class:`machine.milling.MillingMachine` given a ``structure`` (a
:class:`~common.modes.ModalModel`) runs this kernel instead of its rigid one. Per drive
sample (5 kHz by default):

1. the axes' position command (:func:`machine.milling.position_command`) and the spindle's
   motor torque (:func:`machine.spindle.spindle_command`, the speed loop);
2. ``nsub`` sub-steps of the cut (:func:`machine.regeneration.regen_substep`): the rigid
   centre is the carriage (moving at its velocity through the sample) plus the
   eccentricity of seed003 (6); the spindle angle advances at the spindle's actual speed,
   which the cutting torque slows (:func:`machine.spindle.spindle_substep`);
3. the force the tool modes pass to the spindle housing, averaged over the sample, acts
   on the carriages through their PID loops (:func:`machine.milling.drive_step`).

So a chatter vibration reaches the axis currents through the structure (the modes'
transmissibility) and the position loops (18 Hz bandwidth by default), and the spindle
current through the speed loop (30 Hz by default): what a CNC's trace sees.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from common.arrays import F64
from common.modes import ModalModel, Mode
from machine import regeneration as rg
from machine.errors import ParameterError
from machine.feed_drives import FeedDriveParams, zoh_terms
from machine.milling import position_command
from machine.spindle import SpindleParams, spindle_command, spindle_substep

#: rows the kernel adds after :class:`machine.milling.MillingMachine`'s nine
EXTRA_ROWS = (
    "qx",
    "qy",
    "nfx",
    "nfy",
    "amp_nonforced",
    "amp_forced",
    "chip_max",
    "cut_torque",
    "spindle_torque",
    "spindle_speed",
    "fx_base",
    "fy_base",
)
#: slowest spindle speed of the flexible-tool machine [rpm] (the memory's reach)
MIN_RPM = 300.0
#: the cut's sub-steps per period of the highest mode
STEPS_PER_MODE_PERIOD = 64

#: A flexible tool for seed 003's machine (our choice; the seed gives no structure): a
#: 10 mm end mill's bending mode at 1200 Hz (8 N/um, damping ratio 0.02) and the
#: spindle's at 350 Hz (40 N/um, 0.05), each in X and Y. Seed 003's cases 1 and 2
#: (1 mm at 1200 rpm, 2 mm at 1800 rpm) are stable on it; 4 mm at 1200 rpm chatters.
DEMO_STRUCTURE = ModalModel(
    (
        Mode.from_stiffness(1200.0, 0.02, 8e6, 0.0),
        Mode.from_stiffness(1200.0, 0.02, 8e6, 90.0),
        Mode.from_stiffness(350.0, 0.05, 4e7, 0.0),
        Mode.from_stiffness(350.0, 0.05, 4e7, 90.0),
    )
)


@njit(cache=True, inline="always")
def _drive_command(drive: F64, ax: F64, i: int, r: float, ts: float) -> float:  # pragma: no cover
    """The PID of :func:`machine.milling.drive_step` alone: the motor force for the sample
    (``ax[i] = [x, v, integral, e_prev]``, the last two updated)."""
    e = r - ax[i, 0]
    ax[i, 2] += ts * e
    u = drive[i, 0] * e + drive[i, 1] * ax[i, 2] + drive[i, 2] * (e - ax[i, 3]) / ts
    ax[i, 3] = e
    return u


@njit(cache=True, inline="always")
def _carriage_substep(
    drive: F64, csub: F64, ax: F64, i: int, f_in: float, dt: float
) -> None:  # pragma: no cover
    """The carriage of :func:`machine.milling.drive_step` over one sub-step (exact step,
    force held) under ``f_in`` (motor plus housing force) and its friction."""
    v = ax[i, 1]
    f = f_in - drive[i, 5] * math.tanh(v / 1e-3)
    e1 = csub[i, 0]
    e2 = csub[i, 1]
    e3 = csub[i, 2]
    b = drive[i, 4]
    e4 = (dt - e3) / b if b > 0.0 else dt * dt / (2.0 * drive[i, 3])
    ax[i, 0] += e3 * v + e4 * f
    ax[i, 1] = e1 * v + e2 * f


class RegenRun(NamedTuple):
    """A block's fixed scalars: the rate, the spindle's reference, the feed, the
    eccentricity."""

    ts: float  # drive sample time [s]
    nsub: int  # cut sub-steps per drive sample
    omega_ref: float  # spindle speed reference [rad/s]
    feed: float  # feed speed [m/s]
    ecc: float  # eccentricity [m]
    ecc_ph: float  # and its angle [rad]


class RegenDrives(NamedTuple):
    """The drives' designs as the kernel takes them (read only)."""

    drive: F64  # the X/Y feed drives (FeedDriveParams.packed())
    csub: F64  # the carriages' exact-step terms over a sub-step (zoh_terms)
    spd: F64  # the spindle drive (SpindleParams.packed())


class RegenAxes(NamedTuple):
    """The machine's motion state (updated in place)."""

    st: F64  # [psi, path_x]
    ax: F64  # per axis [x, v, integral, e_prev]
    sp_state: F64  # the spindle's [omega, integral, torque]


@njit(cache=True)
def _regen_milling_block(
    n: int,
    run: RegenRun,
    cmd: F64,
    drives: RegenDrives,
    axes: RegenAxes,
    cut: rg.RegenCut,
    mem: rg.RegenMemory,
    out: F64,
) -> None:  # pragma: no cover
    """``n`` drive samples of ``run``; ``axes`` the axes' and the spindle's states;
    ``cmd = [a_m, theta_m, b_m, phi_m, ex_a, ex_order]``; ``drives.csub`` the carriages'
    exact-step terms over a sub-step; ``out`` rows: the rigid kernel's nine, then
    :data:`EXTRA_ROWS`."""
    ts, nsub, omega_ref, feed, ecc, ecc_ph = run
    drive, csub, spd = drives.drive, drives.csub, drives.spd
    st, ax, sp_state = axes.st, axes.ax, axes.sp_state
    truth = mem.truth
    dt = ts / nsub
    sub = np.zeros(len(rg.SUB_ROWS))
    u = np.zeros(2)
    for k in range(n):
        psi = st[0]
        rx, ry = position_command(psi, st[1], cmd[0], cmd[1], cmd[2], cmd[3], cmd[4], cmd[5])
        tm = spindle_command(spd, sp_state, omega_ref, ts)
        out[2, k] = ax[0, 0]
        out[3, k] = ax[1, 0]
        for i in range(2):
            # the CNC's PID on the position at the sample (as machine.milling.drive_step)
            u[i] = _drive_command(drive, ax, i, rx if i == 0 else ry, ts)
        fwx = fwy = fbx = fby = tq = hmax = 0.0
        p0 = psi
        for _ in range(nsub):
            p1 = p0 + sp_state[0] * dt
            x0 = ax[0, 0]
            y0 = ax[1, 0]
            rg.regen_substep(
                p0, p1,
                x0 + ecc * math.cos(p0 + ecc_ph),
                y0 + ecc * math.sin(p0 + ecc_ph),
                x0 + ax[0, 1] * dt + ecc * math.cos(p1 + ecc_ph),
                y0 + ax[1, 1] * dt + ecc * math.sin(p1 + ecc_ph),
                dt, cut, mem, sub,
            )  # fmt: skip
            # the carriages carry the spindle housing: they feel, sub-step by sub-step,
            # what the tool modes pass on, under the motor force held over the sample
            _carriage_substep(drive, csub, ax, 0, u[0] + sub[4], dt)
            _carriage_substep(drive, csub, ax, 1, u[1] + sub[5], dt)
            # the dynamometer reads the force on the workpiece: minus the tool's
            fwx -= sub[0] / nsub
            fwy -= sub[1] / nsub
            fbx += sub[4] / nsub
            fby += sub[5] / nsub
            tq += sub[6] / nsub
            hmax = max(hmax, sub[11])
            spindle_substep(spd, sp_state, sub[6], dt)
            p0 = p1
        out[0, k] = fwx
        out[1, k] = fwy
        out[4, k] = rx
        out[5, k] = ry
        out[6, k] = u[0]
        out[7, k] = u[1]
        out[8, k] = psi
        for i in range(4):
            out[9 + i, k] = sub[7 + i]
        out[13, k] = truth[rg.T_ANF]
        out[14, k] = truth[rg.T_AF]
        out[15, k] = hmax
        out[16, k] = tq
        out[17, k] = tm
        out[18, k] = sp_state[0]
        out[19, k] = fbx
        out[20, k] = fby
        st[0] = p0
        st[1] += feed * ts


class RegenState:
    """The flexible tool's part of the machine's state: modes, twin, memory, spindle."""

    def __init__(
        self,
        structure: ModalModel,
        spindle: SpindleParams,
        ts: float,
        steps_per_mode_period: int,
        n_flutes: int,
        passes: int,
    ) -> None:
        if not isinstance(structure, ModalModel):
            raise ParameterError("structure", "a ModalModel", type(structure).__name__)
        if int(steps_per_mode_period) != steps_per_mode_period or steps_per_mode_period < 16:
            raise ParameterError("steps_per_mode_period", "an integer >= 16", steps_per_mode_period)
        self.structure = structure
        self.spindle = spindle
        self.nsub = max(1, math.ceil(ts * steps_per_mode_period * structure.highest_hz))
        self.dt = ts / self.nsub
        self.disc = rg.discretise(structure, self.dt)
        self.modes = structure.packed()
        self.spd = spindle.packed()
        self.n_flutes = n_flutes
        self.passes = passes
        k = len(structure.modes)
        self.eta = np.zeros((k, 2))
        self.eta_f = np.zeros((k, 2))
        self.truth = rg.new_truth()
        self.past = np.zeros((max(passes, 4), 4))
        self.hmeta = np.zeros(2, dtype=np.int64)
        self.hist = np.zeros((1, rg.H_COLS))
        self.sp_state = np.zeros(3)
        self.csub = np.zeros((2, 3))

    def carriage_terms(self, drives: FeedDriveParams) -> None:
        """The carriages' exact-step terms over one sub-step (:func:`zoh_terms`)."""
        self.csub = np.array([zoh_terms(a.mass, a.viscous, self.dt) for a in (drives.x, drives.y)])

    def reset(self, omega: float, feed: float, ecc: float, ecc_ph: float) -> None:
        """A steady cut's past, the modes still, the spindle at speed."""
        rpm = omega * 60.0 / (2.0 * math.pi)
        need = rg.history_length(self.n_flutes, self.passes, min(rpm, 3000.0), self.dt)
        self.hist = np.zeros((need, rg.H_COLS))
        rg.fill_history(self.hist, self.hmeta, self.dt, omega, feed, ecc, ecc_ph)
        self.eta[:] = 0.0
        self.eta_f[:] = 0.0
        self.truth = rg.new_truth()
        # the loop holds the speed against friction: integral at b w / ki
        self.sp_state[:] = (omega, self.spd[3] * omega / self.spd[2], self.spd[3] * omega)

    def reach(self, rpm: float) -> None:
        """Grow the memory if ``rpm`` needs a longer reach back."""
        if rpm < MIN_RPM:
            raise ParameterError("spindle_rpm", f"a speed >= {MIN_RPM:g} rpm with a structure", rpm)
        need = rg.history_length(self.n_flutes, self.passes, rpm, self.dt)
        if need > self.hist.shape[0]:
            self.hist, self.hmeta = rg.grow_history(self.hist, self.hmeta, need)


def run_block(
    rs: RegenState,
    n: int,
    ts: float,
    omega_ref: float,
    feed: float,
    cmd: F64,
    geometry: tuple[F64, F64, F64, float, float],
    drive: F64,
    st: F64,
    ax: F64,
) -> F64:
    """Run ``n`` drive samples; ``geometry = (cutp, lags, runout, ecc, ecc_phase)``.
    Returns the output rows (nine, then :data:`EXTRA_ROWS`)."""
    cutp, lags, runout, ecc, ecc_ph = geometry
    out = np.empty((9 + len(EXTRA_ROWS), n))
    _regen_milling_block(
        n,
        RegenRun(ts, rs.nsub, omega_ref, feed, ecc, ecc_ph),
        cmd,
        RegenDrives(drive, rs.csub, rs.spd),
        RegenAxes(st, ax, rs.sp_state),
        rg.RegenCut(cutp, lags, runout, rs.modes, rs.disc),
        rg.RegenMemory(rs.eta, rs.eta_f, rs.hist, rs.hmeta, rs.truth, rs.past),
        out,
    )
    return out


__all__ = [
    "DEMO_STRUCTURE",
    "EXTRA_ROWS",
    "MIN_RPM",
    "STEPS_PER_MODE_PERIOD",
    "RegenState",
    "run_block",
]
