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

import numpy as np
from numba import njit

from common.arrays import F64
from common.modes import ModalModel
from machine import regeneration as rg
from machine.errors import ParameterError
from machine.milling import drive_step, position_command
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


@njit(cache=True)
def _regen_milling_block(
    n: int,
    ts: float,
    nsub: int,
    omega_ref: float,
    feed: float,
    cmd: F64,
    ecc: float,
    ecc_ph: float,
    drive: F64,
    spd: F64,
    st: F64,
    ax: F64,
    sp_state: F64,
    cutp: F64,
    lags: F64,
    runout: F64,
    modes: F64,
    disc: F64,
    eta: F64,
    eta_f: F64,
    hist: F64,
    hmeta: np.ndarray,
    truth: F64,
    past: F64,
    out: F64,
) -> None:  # pragma: no cover
    """``n`` drive samples; ``st = [psi, path_x]``, ``ax`` the axes' states, ``sp_state``
    the spindle's; ``cmd = [a_m, theta_m, b_m, phi_m, ex_a, ex_order]``; ``out`` rows:
    the rigid kernel's nine, then :data:`EXTRA_ROWS`."""
    dt = ts / nsub
    sub = np.zeros(len(rg.SUB_ROWS))
    for k in range(n):
        psi = st[0]
        rx, ry = position_command(psi, st[1], cmd[0], cmd[1], cmd[2], cmd[3], cmd[4], cmd[5])
        tm = spindle_command(spd, sp_state, omega_ref, ts)
        x0 = ax[0, 0]
        y0 = ax[1, 0]
        vx = ax[0, 1]
        vy = ax[1, 1]
        fwx = fwy = fbx = fby = tq = hmax = 0.0
        p0 = psi
        for s in range(nsub):
            p1 = p0 + sp_state[0] * dt
            rg.regen_substep(
                p0, p1,
                x0 + vx * s * dt + ecc * math.cos(p0 + ecc_ph),
                y0 + vy * s * dt + ecc * math.sin(p0 + ecc_ph),
                x0 + vx * (s + 1) * dt + ecc * math.cos(p1 + ecc_ph),
                y0 + vy * (s + 1) * dt + ecc * math.sin(p1 + ecc_ph),
                dt, cutp, lags, runout, modes, disc, eta, eta_f, hist, hmeta, truth, past, sub,
            )  # fmt: skip
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
        out[2, k] = x0
        out[3, k] = y0
        out[4, k] = rx
        out[5, k] = ry
        out[8, k] = psi
        for i in range(2):
            # the carriage carries the spindle housing: it feels what the tool modes pass
            # on (drive_step takes the force on the workpiece, its reaction acts)
            out[6 + i, k] = drive_step(
                drive, ax, i, rx if i == 0 else ry, -fbx if i == 0 else -fby, ts
            )
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
        self.past = np.zeros((passes, 4))
        self.hmeta = np.zeros(2, dtype=np.int64)
        self.hist = np.zeros((1, 5))
        self.sp_state = np.zeros(3)

    def reset(self, omega: float, feed: float, ecc: float, ecc_ph: float) -> None:
        """A steady cut's past, the modes still, the spindle at speed."""
        rpm = omega * 60.0 / (2.0 * math.pi)
        need = rg.history_length(self.n_flutes, self.passes, min(rpm, 3000.0), self.dt)
        self.hist = np.zeros((need, 5))
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
        n, ts, rs.nsub, omega_ref, feed, cmd, ecc, ecc_ph, drive, rs.spd, st, ax,
        rs.sp_state, cutp, lags, runout, rs.modes, rs.disc, rs.eta, rs.eta_f, rs.hist,
        rs.hmeta, rs.truth, rs.past, out,
    )  # fmt: skip
    return out


__all__ = ["EXTRA_ROWS", "MIN_RPM", "STEPS_PER_MODE_PERIOD", "RegenState", "run_block"]
