r"""Helical end milling with tool eccentricity, cut by the X/Y feed drives (seed 003).

The machine simulated here is a spindle carried by two servo axes
(:mod:`machine.feed_drives`) cutting a workpiece that stands still. Every sample:

1. the spindle angle :math:`\psi` advances by :math:`\omega_{sp} T_s`;
2. the position command of the axes is the straight feed path plus the circular
   modulation of seed003 (7), :math:`a_m[\cos(\psi+\theta_m), \sin(\psi+\theta_m)]`;
3. the geometric tool centre relative to the workpiece is the carriage position plus the
   eccentricity vector of seed003 (6), :math:`\epsilon[\cos(\psi+\theta_\epsilon),
   \sin(\psi+\theta_\epsilon)]` — eccentricity and modulation add up here;
4. the chip of every flute and axial layer is the displacement of the tool centre since
   the previous flute passed the same angle, projected on the edge's radial direction
   (seed003 (4) with the windowing of seed003 (5)); this is the paper's ``h_n + r_j - r_{j-1}``
   written in workpiece coordinates, so the modulation and drive errors enter the chip
   the same way the eccentricity does;
5. linear edge-force law per layer gives the force; the force acts back on the axes.

Geometry (a choice: the paper gives seed003 (6)-(7) in a frame where the spindle turns
counter-clockwise, so this frame is used): X is the feed direction, Y the normal
direction, the spindle turns counter-clockwise, an edge at immersion angle :math:`\phi`
points along :math:`n(\phi) = [\sin\phi, -\cos\phi]`, so the nominal chip is
:math:`c\sin\phi` (seed003 (4)). Up-milling engages :math:`\phi \in [0, \arccos(1-2a_e/D)]`,
down-milling :math:`\phi \in [\arccos(2a_e/D-1), \pi]`.

Cutting coefficients for Al6061-T6 (a choice; the paper does not give them):
``K_tc = 700 N/mm^2, K_rc = 210 N/mm^2, K_te = 20 N/mm, K_re = 25 N/mm``. These are in
the range of mechanistic coefficients reported for 6061-T6 with carbide end mills, e.g.
Schmitz & Smith, *Machining Dynamics* (Springer, 2009; tangential ~ 700-800 N/mm^2,
normal/radial ratio ~ 0.3) and Altintas, *Manufacturing Automation* (2nd ed., 2012,
Al7050 example: 796 / 168.8 N/mm^2, edge 27.7 / 30.8 N/mm).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
from numba import njit

from common.arrays import F64
from common.modes import ModalModel
from machine.errors import ParameterError, require_in, require_nonnegative, require_positive
from machine.feed_drives import FeedDriveParams, FeedDrives
from machine.regeneration import ChatterTruth, pack_cut
from machine.spindle import SpindleParams

if TYPE_CHECKING:
    from machine.milling_regen import RegenState

#: Slowest spindle the chip history is sized for [rpm] (the tooth period must fit).
MIN_RPM = 60.0
#: Largest modulation radius the axes accept [m] (a CNC limit; larger is clamped).
MAX_MODULATION = 100e-6


@dataclass(frozen=True)
class MillingParams:
    r"""Cutter, cut and eccentricity (SI units: m, N, rad where not stated).

    Parameters
    ----------
    n_flutes : int
        Number of flutes :math:`N_f` (>= 1).
    diameter : float
        Tool diameter :math:`D` [m].
    helix_deg : float
        Helix angle :math:`\beta` [deg], in [0, 60].
    axial_depth : float
        Axial depth of cut :math:`a_p` [m].
    radial_immersion : float
        Radial width of cut over diameter, in (0, 1].
    down_milling : bool
        Down (climb) milling if true, up (conventional) milling otherwise.
    feed_per_tooth : float
        Feed per tooth :math:`c` [m].
    spindle_rpm : float
        Spindle speed [rpm].
    eccentricity : float
        Eccentricity radius :math:`\epsilon` [m] (seed003 (2)).
    eccentricity_deg : float
        Eccentricity phase :math:`\theta_\epsilon` [deg] (seed003 (2)).
    k_tc, k_rc : float
        Tangential and radial cutting coefficients [N/m^2].
    k_te, k_re : float
        Tangential and radial edge coefficients [N/m].
    n_layers : int
        Axial layers :math:`N_l` of seed003 (1).
    """

    n_flutes: int = 4
    diameter: float = 10e-3
    helix_deg: float = 30.0
    axial_depth: float = 1e-3
    radial_immersion: float = 0.2
    down_milling: bool = False
    feed_per_tooth: float = 80e-6
    spindle_rpm: float = 1200.0
    eccentricity: float = 20e-6
    eccentricity_deg: float = 40.0
    k_tc: float = 700e6
    k_rc: float = 210e6
    k_te: float = 20e3
    k_re: float = 25e3
    n_layers: int = 10

    def __post_init__(self) -> None:
        if int(self.n_flutes) != self.n_flutes or self.n_flutes < 1:
            raise ParameterError("n_flutes", "an integer >= 1", self.n_flutes)
        require_positive("diameter", self.diameter)
        require_in("helix_deg", self.helix_deg, 0.0, 60.0)
        require_positive("axial_depth", self.axial_depth)
        require_in("radial_immersion", self.radial_immersion, 0.0, 1.0, lo_open=True)
        require_positive("feed_per_tooth", self.feed_per_tooth)
        if self.feed_per_tooth > 0.5 * self.diameter:
            raise ParameterError("feed_per_tooth", "a value <= D/2", self.feed_per_tooth)
        check_rpm(self.spindle_rpm)
        require_nonnegative("eccentricity", self.eccentricity)
        if self.eccentricity > 0.05 * self.diameter:
            raise ParameterError("eccentricity", "a value <= D/20", self.eccentricity)
        if not math.isfinite(self.eccentricity_deg):
            raise ParameterError("eccentricity_deg", "a finite angle", self.eccentricity_deg)
        for name in ("k_tc", "k_rc", "k_te", "k_re"):
            require_nonnegative(name, getattr(self, name))
        if int(self.n_layers) != self.n_layers or not 1 <= self.n_layers <= 200:
            raise ParameterError("n_layers", "an integer in [1, 200]", self.n_layers)

    @property
    def spindle_hz(self) -> float:
        return self.spindle_rpm / 60.0

    def engagement(self) -> tuple[float, float]:
        r"""Entry and exit angles :math:`(\phi_{st}, \phi_{ex})` [rad] of seed003 (5)."""
        r = self.radial_immersion
        if self.down_milling:
            return math.acos(2.0 * r - 1.0), math.pi
        return 0.0, math.acos(1.0 - 2.0 * r)

    def layer_lags(self) -> F64:
        r"""Lag angle of each axial layer (seed003 (1)): :math:`2 z_l \tan\beta / D`, layer mid
        heights :math:`z_l = (l - 1/2) a_p / N_l`."""
        z = (np.arange(self.n_layers) + 0.5) * self.axial_depth / self.n_layers
        return np.asarray(2.0 * z * math.tan(math.radians(self.helix_deg)) / self.diameter)


def check_rpm(rpm: float) -> float:
    """Return ``rpm`` as float if it is a spindle speed the model accepts."""
    v = float(rpm)
    if not math.isfinite(v) or v < MIN_RPM or v > 60000.0:
        raise ParameterError("spindle_rpm", f"a speed in [{MIN_RPM:g}, 60000] rpm", rpm)
    return v


@njit(cache=True)
def edge_force(
    phi: float,
    dpx: float,
    dpy: float,
    dz: float,
    k_tc: float,
    k_rc: float,
    k_te: float,
    k_re: float,
    phi_st: float,
    phi_ex: float,
) -> tuple[float, float]:  # pragma: no cover
    """Force on the workpiece from one edge element at immersion ``phi``.

    ``(dpx, dpy)`` is the displacement of the tool centre since the previous flute.
    """
    two_pi = 2.0 * math.pi
    p = phi
    if p < 0.0 or p >= two_pi:
        p = phi % two_pi
    # seed003 (5): the window g(phi)
    if p < phi_st or p > phi_ex:
        return 0.0, 0.0
    s = math.sin(p)
    c = math.cos(p)
    # seed003 (4): h = h_n + (r_j - r_{j-1}), as the tool-centre displacement since the
    # previous flute projected on n(phi) = [sin, -cos]; feed alone gives h = c_f sin(phi)
    h = dpx * s - dpy * c
    if h <= 0.0:
        # the edge is out of the material (the paper's seed003 (4) would give a negative chip)
        return 0.0, 0.0
    ft = k_tc * dz * h + k_te * dz
    fr = k_rc * dz * h + k_re * dz
    # force on the tool: -ft along the edge velocity [cos, sin], -fr along n(phi);
    # the workpiece (dynamometer) sees the opposite
    return ft * c + fr * s, ft * s - fr * c


@njit(cache=True)
def drive_step(
    drive: F64, ax_state: F64, i: int, r: float, f_work: float, ts: float
) -> float:  # pragma: no cover
    """One sample of axis ``i``: the PID on the position error, then the carriage over the
    sample (exact zero-order hold, :func:`machine.feed_drives.zoh_terms`) under the motor
    force, friction and the reaction ``-f_work`` of the force on the workpiece.

    ``drive`` is :meth:`FeedDriveParams.packed`, ``ax_state[i] = [x, v, integral,
    e_prev]`` (updated); returns the motor force ``u`` [N].
    """
    kp = drive[i, 0]
    ki = drive[i, 1]
    kd = drive[i, 2]
    b = drive[i, 4]
    fc = drive[i, 5]
    e1 = drive[i, 6]
    e2 = drive[i, 7]
    e3 = drive[i, 8]
    x = ax_state[i, 0]
    v = ax_state[i, 1]
    e = r - x
    ax_state[i, 2] += ts * e
    u = kp * e + ki * ax_state[i, 2] + kd * (e - ax_state[i, 3]) / ts
    ax_state[i, 3] = e
    f = u - f_work - fc * math.tanh(v / 1e-3)
    if b > 0.0:
        e4 = (ts - e3) / b
    else:
        e4 = ts * ts / (2.0 * drive[i, 3])
    ax_state[i, 0] = x + e3 * v + e4 * f
    ax_state[i, 1] = e1 * v + e2 * f
    return u


@njit(cache=True, inline="always")
def position_command(
    psi: float,
    path_x: float,
    a_m: float,
    theta_m: float,
    b_m: float,
    phi_m: float,
    ex_a: float,
    ex_order: float,
) -> tuple[float, float]:  # pragma: no cover
    """The axes' position command at spindle angle ``psi``: the feed path ``path_x`` plus
    the modulation circles (shared by every kernel that drives these axes)."""
    # seed003 (7): circular modulation added to the feed path in the position command
    rx = path_x + a_m * math.cos(psi + theta_m)
    ry = a_m * math.sin(psi + theta_m)
    # beyond the paper: a counter-rotating circle (with seed003 (7) it makes an ellipse,
    # which can undo a gain/phase mismatch between the axes)
    # (skipped when b_m is 0 and the sum is not a zero whose sign the term could
    # flip: x + 0 and x - 0 are x for x != 0, so the values are the same bits)
    if b_m != 0.0 or rx == 0.0 or ry == 0.0:
        rx += b_m * math.cos(psi + phi_m)
        ry -= b_m * math.sin(psi + phi_m)
    # beyond the paper: a small identification circle at spindle order ex_order (an
    # observer identifies the axis mass from it; 0 by default)
    if ex_a != 0.0:
        rx += ex_a * math.cos(ex_order * psi)
        ry += ex_a * math.sin(ex_order * psi)
    return rx, ry


#: margin of :func:`_flute_idle` [rad] (the angles' rounding is ~1e-15 rad)
_IDLE_MARGIN = 1e-9


@njit(cache=True)
def _flute_idle(
    base: float, lag_max: float, phi_st: float, phi_ex: float
) -> bool:  # pragma: no cover
    """True when every layer of a flute at ``base`` (its immersion before the layer lags,
    ``phi = base - lag`` wrapped into [0, 2 pi) with ``0 <= lag <= lag_max``) lies
    outside the window ``[phi_st, phi_ex]`` by more than a margin, so
    :func:`edge_force` gives exact zeros for all of them."""
    two_pi = 2.0 * math.pi
    b = base
    while b < 0.0:
        b += two_pi
    lo = b - lag_max
    if lo - _IDLE_MARGIN <= 0.0 or b + _IDLE_MARGIN >= two_pi:
        return False  # the layers may wrap: decide per layer
    return lo > phi_ex + _IDLE_MARGIN or b < phi_st - _IDLE_MARGIN


class MillingCut(NamedTuple):
    """The cut as the rigid kernel takes it (read only over a block)."""

    ts: float  # sample time [s]
    n_flutes: int
    lags: F64  # each axial layer's lag [rad] (helix)
    dz: float  # layer height [m]
    phi_st: float  # immersion window: start [rad]
    phi_ex: float  # and exit [rad]
    kc: F64  # [K_tc, K_rc, K_te, K_re]
    ecc: float  # eccentricity [m]
    ecc_phase: float  # its angle [rad]
    omega: float  # spindle speed [rad/s]
    feed_speed: float  # [m/s]


class Modulation(NamedTuple):
    """The position command's circles held over a block (seed003 (7)) and the
    identification circle: :func:`position_command`'s inputs after the angle and path."""

    a_m: float  # co-rotating circle radius [m]
    theta_m: float  # and its phase [rad]
    b_m: float  # counter-rotating circle radius [m]
    phi_m: float  # and its phase [rad]
    ex_a: float  # identification circle radius [m]
    ex_order: float  # and its spindle order


@njit(cache=True)
def _milling_block(n, cut, cmd, drive, st, ax_state, hist, out):  # pragma: no cover
    """Advance the machine ``n`` samples of the cut ``cut`` (:class:`MillingCut`) with the
    command ``cmd`` (:class:`Modulation`) held.

    ``st = [psi, path_x, head]``; ``ax_state[i] = [x, v, integral, e_prev]`` per axis;
    ``hist[k] = [px, py]`` ring buffer of tool-centre positions; ``out`` rows are
    ``fx, fy, x, y, rx, ry, ux, uy, psi``.
    """
    ts, n_flutes, lags, dz, phi_st, phi_ex = (
        cut.ts, cut.n_flutes, cut.lags, cut.dz, cut.phi_st, cut.phi_ex
    )  # fmt: skip
    kc, ecc, ecc_phase, omega, feed_speed = (
        cut.kc,
        cut.ecc,
        cut.ecc_phase,
        cut.omega,
        cut.feed_speed,
    )
    a_m, theta_m, b_m, phi_m, ex_a, ex_order = cmd
    hlen = hist.shape[0]
    pitch = 2.0 * math.pi / n_flutes
    lag_max = 0.0
    for l in range(lags.shape[0]):
        lag_max = max(lag_max, lags[l])
    tau = pitch / omega
    lag_samples = tau / ts
    # F = sum over flutes j and layers l of the edge force at phi_jl (seed003 (1)-(5)), tool centre
    #  per seed003 (6)-(7)
    for k in range(n):
        psi = st[0]
        rx, ry = position_command(psi, st[1], a_m, theta_m, b_m, phi_m, ex_a, ex_order)
        # seed003 (6): geometric tool centre = carriage + eccentricity (workpiece coordinates)
        px = ax_state[0, 0] + ecc * math.cos(psi + ecc_phase)
        py = ax_state[1, 0] + ecc * math.sin(psi + ecc_phase)
        head = int(st[2])
        hist[head, 0] = px
        hist[head, 1] = py
        # tool centre one tooth period ago (linear interpolation in the history)
        back = lag_samples
        i0 = math.floor(back)
        fr = back - i0
        ia = (head - i0) % hlen
        ib = (head - i0 - 1) % hlen
        qx = (1.0 - fr) * hist[ia, 0] + fr * hist[ib, 0]
        qy = (1.0 - fr) * hist[ia, 1] + fr * hist[ib, 1]
        dpx = px - qx
        dpy = py - qy
        fx = 0.0
        fy = 0.0
        p0 = psi % (2.0 * math.pi)
        for j in range(n_flutes):
            # a flute whose layers all lie outside the window adds exact zeros: skipped
            # (the test has a margin far beyond the rounding of the angles below)
            if _flute_idle(p0 - j * pitch, lag_max, phi_st, phi_ex):
                continue
            for l in range(lags.shape[0]):
                # seed003 (1): immersion of flute j, layer l (wrapped into [0, 2 pi))
                phi = p0 - j * pitch - lags[l]
                while phi < 0.0:
                    phi += 2.0 * math.pi
                ex, ey = edge_force(phi, dpx, dpy, dz, kc[0], kc[1], kc[2], kc[3], phi_st, phi_ex)
                fx += ex
                fy += ey
        out[0, k] = fx
        out[1, k] = fy
        out[2, k] = ax_state[0, 0]
        out[3, k] = ax_state[1, 0]
        out[4, k] = rx
        out[5, k] = ry
        out[8, k] = psi
        for i in range(2):
            # the tool feels the reaction of the force on the workpiece
            out[6 + i, k] = drive_step(
                drive, ax_state, i, rx if i == 0 else ry, fx if i == 0 else fy, ts
            )
        st[0] = psi + omega * ts
        st[1] += feed_speed * ts
        st[2] = (head + 1) % hlen


@dataclass
class MillingRecord:
    """Outputs of one block (arrays of the block length).

    ``fx, fy`` force on the workpiece [N] (what a dynamometer reads); ``x, y`` carriage
    positions [m]; ``rx, ry`` position commands [m]; ``ix, iy`` motor currents [A];
    ``psi`` spindle angle [rad] (unwrapped); ``t`` time [s].
    """

    t: F64
    fx: F64
    fy: F64
    x: F64
    y: F64
    rx: F64
    ry: F64
    ix: F64
    iy: F64
    psi: F64
    a_m: float
    theta_m: float
    saturated: bool
    b_m: float = 0.0
    phi_m: float = 0.0
    #: with a flexible tool (``structure``): :data:`machine.milling_regen.EXTRA_ROWS`,
    #: plus ``spindle_current`` [A] and ``spindle_power`` [W]; ``None`` otherwise
    chatter: dict[str, F64] | None = None


@dataclass
class _State:
    st: F64
    ax: F64
    hist: F64
    k: int = 0


class MillingMachine:
    """The spindle on its X/Y feed drives, cutting; a block step with the modulation held.

    Parameters
    ----------
    milling : MillingParams
        Cutter, cut and eccentricity.
    drives : FeedDriveParams
        The two servo axes and the sample time (5 kHz by default).
    max_modulation : float
        Largest modulation radius accepted [m]; larger requests are clamped and the block
        record says ``saturated``.
    structure : ModalModel, optional
        The tool's (and workpiece's) modes: the cut regenerates (chatter) through
        :mod:`machine.milling_regen`; the spindle then has a speed loop (``spindle``).
        Without it the tool is rigid and the machine is seed 003's, unchanged.
    spindle : SpindleParams, optional
        The spindle drive with a ``structure`` (default :class:`SpindleParams()`).

    Examples
    --------
    >>> m = MillingMachine(MillingParams())
    >>> rec = m.step(m.samples_per_revolution(), a_m=0.0, theta_m=0.0)
    """

    def __init__(
        self,
        milling: MillingParams | None = None,
        drives: FeedDriveParams | None = None,
        *,
        max_modulation: float = MAX_MODULATION,
        structure: ModalModel | None = None,
        spindle: SpindleParams | None = None,
    ) -> None:
        self.milling = milling if milling is not None else MillingParams()
        self.drives = FeedDrives(drives)
        self.max_modulation = require_positive("max_modulation", max_modulation)
        self._drive = self.drives.params.packed()
        p = self.milling
        self._lags = p.layer_lags()
        self._kc = np.array([p.k_tc, p.k_rc, p.k_te, p.k_re])
        self._window = p.engagement()
        self._rpm = self.milling.spindle_rpm
        self.excitation: tuple[float, float] = (0.0, 0.0)
        self._flex: RegenState | None = None
        if structure is not None:
            from machine.milling_regen import STEPS_PER_MODE_PERIOD, RegenState

            p = self.milling
            self._flex = RegenState(
                structure,
                spindle if spindle is not None else SpindleParams(),
                self.sample_time,
                STEPS_PER_MODE_PERIOD,
                int(p.n_flutes),
                max(4, 2 * int(p.n_flutes)),
            )
            self._flex.reach(self._rpm)
            self._flex.carriage_terms(self.drives.params)
        self.chatter_truth = ChatterTruth()
        self.reset()

    @property
    def sample_time(self) -> float:
        return self.drives.params.sample_time

    @property
    def substeps(self) -> int:
        """Sub-steps of the cut per drive sample (1 with a rigid tool)."""
        return 1 if self._flex is None else self._flex.nsub

    @property
    def structure(self) -> ModalModel | None:
        """The flexible tool's modes (``None``: a rigid tool, seed 003's machine)."""
        return None if self._flex is None else self._flex.structure

    @property
    def spindle_rpm(self) -> float:
        return self._rpm

    @property
    def t(self) -> float:
        return self._s.k * self.sample_time

    @property
    def spindle_angle(self) -> float:
        """Unwrapped spindle angle [rad] of the next sample."""
        return float(self._s.st[0])

    def samples_per_revolution(self) -> float:
        """:math:`L = 60 / (T_s \\cdot rpm)` of seed003 (8) (not necessarily an integer)."""
        return 60.0 / (self.sample_time * self._rpm)

    def feed_speed(self) -> float:
        """Feed rate [m/s] at the current spindle speed (feed per tooth held)."""
        p = self.milling
        return p.feed_per_tooth * p.n_flutes * self._rpm / 60.0

    def set_excitation(self, amplitude: float, order: float) -> None:
        """Add (or, with ``amplitude`` 0, remove) an identification circle to the position
        command of both axes: ``amplitude [cos(order psi), sin(order psi)]`` [m], at the
        spindle order ``order`` (beyond the paper; an adaptive observer identifies the
        axis mass from it, see :mod:`estimators.axis_mass`)."""
        a = require_nonnegative("amplitude", amplitude)
        if a > self.max_modulation:
            raise ParameterError("amplitude", f"a value <= {self.max_modulation:g} m", amplitude)
        o = require_positive("order", order)
        self.excitation = (float(a), float(o))

    def set_spindle_rpm(self, rpm: float) -> None:
        """Change the spindle speed (the feed rate follows, feed per tooth held). With a
        flexible tool the speed loop takes the machine there (its bandwidth)."""
        v = check_rpm(rpm)
        if self._flex is not None:
            self._flex.reach(v)
        self._rpm = v

    def set_axial_depth(self, depth: float) -> None:
        """Change the axial depth of cut now (a step in the workpiece)."""
        self.milling = replace(self.milling, axial_depth=depth)
        self._lags = self.milling.layer_lags()

    def reset(self) -> None:
        """Steady cut at the nominal feed, no modulation, history filled with the path."""
        self._rpm = self.milling.spindle_rpm
        ts = self.sample_time
        hlen = math.ceil(60.0 / (MIN_RPM * self.milling.n_flutes) / ts) + 8
        v = self.feed_speed()
        p = self.milling
        ecc = p.eccentricity
        th = math.radians(p.eccentricity_deg)
        omega = 2.0 * math.pi * self._rpm / 60.0
        hist = np.zeros((hlen, 2))
        # the past: straight path at the feed rate, eccentric centre turning (seed003 (6)). The
        # kernel writes the sample at t = 0 into index 0 and reads m samples back at
        # (head - m) % hlen, so index hlen - m holds t = -m ts
        for m in range(1, hlen):
            tb = -m * ts
            hist[hlen - m, 0] = v * tb + ecc * math.cos(omega * tb + th)
            hist[hlen - m, 1] = ecc * math.sin(omega * tb + th)
        ax = np.zeros((2, 4))
        ax[0, 1] = v
        _, ki, _ = self.drives.params.x.gains()
        # integral state holding the viscous + Coulomb force of the steady feed
        xp = self.drives.params.x
        ax[0, 2] = (xp.viscous * v + xp.coulomb * math.tanh(v / 1e-3)) / ki
        self._s = _State(st=np.array([0.0, 0.0, 0.0]), ax=ax, hist=hist)
        if self._flex is not None:
            self._flex.reset(omega, v, ecc, th)
            self.chatter_truth = ChatterTruth()

    def cancelling_modulation(self, rpm: float | None = None) -> tuple[float, float]:
        """Truth: the ``(a_m [m], theta_m [rad])`` whose drive response cancels seed003 (6).

        At the spindle speed ``rpm`` (default: the current one). The carriage
        moves :math:`G a_m e^{j\\theta_m}` and must equal :math:`-\\epsilon
        e^{j\\theta_\\epsilon}`. With mismatched axes no circle cancels exactly; this is
        the cancellation by the mean response :math:`(G_x + G_y)/2`.
        """
        gx, gy = self.drives.response((self._rpm if rpm is None else check_rpm(rpm)) / 60.0)
        g = 0.5 * (gx + gy)
        p = self.milling
        target = -p.eccentricity * complex(
            math.cos(math.radians(p.eccentricity_deg)), math.sin(math.radians(p.eccentricity_deg))
        )
        u = target / g
        return abs(u), math.atan2(u.imag, u.real) % (2.0 * math.pi)

    def step(
        self,
        n: int,
        a_m: float = 0.0,
        theta_m: float = 0.0,
        b_m: float = 0.0,
        phi_m: float = 0.0,
    ) -> MillingRecord:
        """Advance ``n`` samples with the modulation ``(a_m [m], theta_m [rad])`` held.

        A negative ``a_m`` is the circle of radius ``|a_m|`` at ``theta_m + pi``.
        ``b_m, phi_m`` add a counter-rotating circle
        :math:`b_m[\\cos(\\psi+\\phi_m), -\\sin(\\psi+\\phi_m)]` (0 in the paper). When
        ``|a_m| + |b_m|`` exceeds ``max_modulation`` both are scaled down and the record
        says ``saturated``.
        """
        if int(n) != n or n < 0:
            raise ParameterError("n", "an integer >= 0", n)
        a = float(a_m)
        th = float(theta_m)
        b = float(b_m)
        ph = float(phi_m)
        if not (math.isfinite(a) and math.isfinite(th) and math.isfinite(b) and math.isfinite(ph)):
            raise ParameterError("a_m/theta_m", "finite values", (a_m, theta_m, b_m, phi_m))
        total = abs(a) + abs(b)
        sat = total > self.max_modulation
        if sat:
            a *= self.max_modulation / total
            b *= self.max_modulation / total
        n = int(n)
        if self._flex is not None:
            return self._flexible_step(self._flex, n, a, th, b, ph, sat)
        p = self.milling
        out = np.empty((9, n))
        st0, ph_ex = self._window
        omega = 2.0 * math.pi * self._rpm / 60.0
        cut = MillingCut(
            ts=self.sample_time,
            n_flutes=int(p.n_flutes),
            lags=self._lags,
            dz=p.axial_depth / p.n_layers,
            phi_st=st0,
            phi_ex=ph_ex,
            kc=self._kc,
            ecc=p.eccentricity,
            ecc_phase=math.radians(p.eccentricity_deg),
            omega=omega,
            feed_speed=self.feed_speed(),
        )
        cmd = Modulation(a, th, b, ph, self.excitation[0], self.excitation[1])
        _milling_block(n, cut, cmd, self._drive, self._s.st, self._s.ax, self._s.hist, out)
        t = np.asarray((self._s.k + np.arange(n)) * self.sample_time, dtype=np.float64)
        self._s.k += n
        kf = (self.drives.params.x.force_constant, self.drives.params.y.force_constant)
        return MillingRecord(
            t=t,
            fx=out[0],
            fy=out[1],
            x=out[2],
            y=out[3],
            rx=out[4],
            ry=out[5],
            ix=out[6] / kf[0],
            iy=out[7] / kf[1],
            psi=out[8],
            a_m=a,
            theta_m=th,
            saturated=sat,
            b_m=b,
            phi_m=ph,
        )

    def _flexible_step(
        self, flex: RegenState, n: int, a: float, th: float, b: float, ph: float, sat: bool
    ) -> MillingRecord:
        """:meth:`step` with the flexible tool (:mod:`machine.milling_regen`)."""
        from machine.milling_regen import EXTRA_ROWS, run_block

        p = self.milling
        cutp = pack_cut(
            int(p.n_flutes),
            self._window,
            (p.k_tc, p.k_rc, p.k_te, p.k_re),
            p.axial_depth / p.n_layers,
            0.5 * p.diameter,
            flex.passes,
        )
        geometry = (cutp, self._lags, np.zeros(int(p.n_flutes)), p.eccentricity,
                    math.radians(p.eccentricity_deg))  # fmt: skip
        cmd = np.array([a, th, b, ph, self.excitation[0], self.excitation[1]])
        out = run_block(
            flex, n, self.sample_time, 2.0 * math.pi * self._rpm / 60.0, self.feed_speed(),
            cmd, geometry, self._drive, self._s.st, self._s.ax,
        )  # fmt: skip
        t = np.asarray((self._s.k + np.arange(n)) * self.sample_time, dtype=np.float64)
        self._s.k += n
        kf = (self.drives.params.x.force_constant, self.drives.params.y.force_constant)
        extra = {name: out[9 + i] for i, name in enumerate(EXTRA_ROWS)}
        extra["spindle_current"] = extra["spindle_torque"] / flex.spindle.torque_constant
        extra["spindle_power"] = extra["spindle_torque"] * extra["spindle_speed"]
        self.chatter_truth.update(
            t, extra["amp_nonforced"], extra["amp_forced"], extra["nfx"], extra["nfy"]
        )
        return MillingRecord(
            t=t, fx=out[0], fy=out[1], x=out[2], y=out[3], rx=out[4], ry=out[5],
            ix=out[6] / kf[0], iy=out[7] / kf[1], psi=out[8], a_m=a, theta_m=th,
            saturated=sat, b_m=b, phi_m=ph, chatter=extra,
        )  # fmt: skip


__all__ = [
    "MAX_MODULATION",
    "MIN_RPM",
    "MillingMachine",
    "MillingParams",
    "MillingRecord",
    "check_rpm",
    "drive_step",
    "edge_force",
]
