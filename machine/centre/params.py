r"""The machining centre's mechanics and drives: its frozen, validated parameters.

A 3-axis vertical machining centre (C-frame): the table (X) on the saddle (Y) carries the
workpiece, the spindle head (Z) carries the tool. Every axis is a servo motor on a ball
screw; the numbers below are our choices for a machine of this size (a 15 kW spindle, an
800 x 500 mm table), each with its reasoning. SI units throughout; every feed axis is
simulated in *linear-equivalent* coordinates along its travel: a motor angle
:math:`\theta` is :math:`x_m = p\,\theta` with :math:`p = \text{lead}/2\pi` [m/rad], a
rotor inertia :math:`J` is a mass :math:`J/p^2`, a motor torque :math:`T` a force
:math:`T/p`.

X: two inertias on a ball screw, with a linear scale
----------------------------------------------------
Motor side: the rotor, the coupling and the screw (their rotation); load side: the table
with its fixture and workpiece; between them the axial stiffness of the screw, its nut
and its fixed bearing, in series with the torsion of the screw and the coupling
(:class:`BallScrew`). With a 40 x 16 mm screw (root 34 mm, fixed-supported, nut 0.55 m
from the fixed bearing at mid travel), nut and bearing at 1000 N/um each, a coupling of
12 kN m/rad: k = 170 N/um, and with 1013 kg of motor-side equivalent mass and 342 kg on
the table the first axial mode is at 130 Hz (anti-resonance 112 Hz), below the 250 Hz
Nyquist frequency of a 500 Hz trace. A screw's stiffness falls as the nut moves away
from the fixed bearing (168-109 Hz as the nut moves from 0.15 to 0.95 m); the simulation
holds the mid-travel value.

Y and Z: semi-closed loop
-------------------------
Only the motor encoder and the current: each is simulated as one rigid mass (rotor,
coupling, screw and load together), the model a semi-closed-loop CNC and an identifier
of ``M, Fv, Fc, offset`` see. Z carries the spindle head against gravity **without a
counterbalance** (a brake motor holds it, as on most machining centres of this size with
a 12 mm lead screw): the Z motor holds 3.9 kN, a constant offset of 5 A.

Controllers (every axis alike, as interpolating axes must be)
--------------------------------------------------------------
Position P loop with velocity and acceleration feed-forward, Kv = 50 1/s (a "servo gain"
of 3 (m/min)/mm), on the linear scale for X and the motor encoder for Y and Z; a PI speed
loop on the motor encoder's speed (crossover ``speed_hz``, integral time
``speed_ti``); a current loop as a first-order lag of bandwidth ``current_hz``. All run
at the simulation rate (10 kHz; the position loop in the drive at the speed-control
cycle, as in Siemens' Dynamic Servo Control). :func:`machine.centre.loops` computes the
closed-loop bandwidths from the discrete loop.

Spindle
-------
A 15 kW motor, 95 N m up to its 1500 rpm base speed, constant power above, 12,000 rpm;
rotor, spindle and tool holder 0.035 kg m^2; a PI speed loop of 30 Hz crossover; friction
Coulomb + viscous, with a warm-up (bearings run-in: the Coulomb part 30 % higher cold,
falling with a 10-minute time constant while it turns). The drive's current is its
torque-producing current; the CNC's power is torque setpoint times measured speed,
smoothed by a first-order lag of ``power_smoothing`` (10 ms, a choice: CNCs smooth their
displayed power over 4-100 ms).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace

from machine.errors import ParameterError, require_in, require_nonnegative, require_positive

#: steel: Young's modulus [Pa], shear modulus [Pa], density [kg/m^3]
STEEL_E = 206e9
STEEL_G = 79.3e9
STEEL_RHO = 7850.0
#: standard gravity [m/s^2]
GRAVITY = 9.81
#: the simulation rate [Hz]: a drive's speed-control cycle (100 us); 500 Hz, 1, 2.5 and
#: 5 kHz traces are whole divisions of it
SIM_RATE_HZ = 10_000.0


@dataclass(frozen=True)
class BallScrew:
    """A ball screw and its bearings; derives the axial stiffness of the drive train.

    Parameters
    ----------
    diameter, root_diameter : float
        Nominal and root (thread bottom) diameter [m].
    lead : float
        Travel per revolution [m].
    length : float
        Screw length [m] (its inertia).
    nut_distance : float
        Distance from the fixed bearing to the nut [m] (fixed-supported mounting: the
        screw's axial stiffness is :math:`E A / L` over this length).
    nut_stiffness, bearing_stiffness : float
        Axial stiffness of the preloaded nut and of the fixed bearing [N/m] (catalogue
        values of 40 mm preloaded double nuts and angular-contact bearing pairs are of
        the order of 1000 N/um).
    coupling_stiffness : float
        Torsional stiffness of the motor coupling [N m/rad].
    coupling_inertia : float
        Its inertia [kg m^2].
    """

    diameter: float = 0.040
    root_diameter: float = 0.034
    lead: float = 0.016
    length: float = 1.2
    nut_distance: float = 0.55
    nut_stiffness: float = 1.0e9
    bearing_stiffness: float = 1.0e9
    coupling_stiffness: float = 12_000.0
    coupling_inertia: float = 0.2e-3

    def __post_init__(self) -> None:
        for f in fields(self):
            require_positive(f.name, getattr(self, f.name))
        if self.root_diameter >= self.diameter:
            raise ParameterError(
                "root_diameter", f"a value < the diameter {self.diameter:g} m", self.root_diameter
            )
        if self.nut_distance >= self.length:
            raise ParameterError(
                "nut_distance", f"a value < the screw length {self.length:g} m", self.nut_distance
            )

    @property
    def p(self) -> float:
        """Travel per radian [m/rad]."""
        return self.lead / (2.0 * math.pi)

    def screw_axial(self, nut_distance: float | None = None) -> float:
        """Axial stiffness of the screw between fixed bearing and nut [N/m]."""
        d = self.nut_distance if nut_distance is None else nut_distance
        area = math.pi * self.root_diameter**2 / 4.0
        return STEEL_E * area / d

    def torsion(self, nut_distance: float | None = None) -> float:
        """Torsional stiffness of the screw from the coupling (0.1 m beyond the bearing) to
        the nut [N m/rad]."""
        d = (self.nut_distance if nut_distance is None else nut_distance) + 0.1
        jp = math.pi * self.root_diameter**4 / 32.0
        return STEEL_G * jp / d

    def stiffness(self, nut_distance: float | None = None) -> float:
        r"""Axial stiffness of the drive train [N/m]: screw, nut and bearing in series with
        the screw's and coupling's torsion seen along the axis (:math:`k_\theta / p^2`)."""
        p2 = self.p**2
        parts = (
            self.screw_axial(nut_distance),
            self.nut_stiffness,
            self.bearing_stiffness,
            self.torsion(nut_distance) / p2,
            self.coupling_stiffness / p2,
        )
        return 1.0 / sum(1.0 / k for k in parts)

    @property
    def screw_inertia(self) -> float:
        """Inertia of the screw shaft (a steel cylinder of the nominal diameter) [kg m^2]."""
        return STEEL_RHO * math.pi * self.diameter**4 * self.length / 32.0


@dataclass(frozen=True)
class FeedAxisParams:
    """One feed axis: drive train, load, friction, motor, measurement and controller.

    Parameters
    ----------
    name : str
        ``X``, ``Y`` or ``Z``.
    kind : str
        ``two_inertia`` (linear scale, the load's position fed back) or ``rigid``
        (semi-closed: the motor encoder only; simulated as one mass).
    screw : BallScrew
    rotor_inertia : float
        Motor rotor inertia [kg m^2] (brake included).
    load_mass : float
        Moving mass on the nut without the workpiece [kg].
    carries_workpiece : bool
        The workpiece rides on this axis (X and Y: its mass adds to the load).
    gravity : bool
        A vertical axis: the load's weight acts along -axis (no counterbalance).
    motor_coulomb, motor_viscous : float
        Motor-side friction (bearings, seals, screw supports) [N m], [N m s/rad].
    load_coulomb, load_viscous : float
        Load-side friction (guides, nut) [N], [N s/m].
    damping_ratio : float
        Damping ratio of the axial mode (two-inertia only).
    torque_constant : float
        Motor torque per ampere [N m/A].
    peak_torque : float
        Torque limit [N m].
    encoder_counts : int
        Motor encoder counts per revolution.
    scale_resolution : float
        Linear scale resolution [m] (two-inertia only).
    current_noise : float
        Rms of the current measurement noise [A]; ``current_lsb`` its quantum [A].
    kv : float
        Position-loop gain [1/s].
    speed_hz, speed_ti : float
        Speed-loop crossover [Hz] (P gain ``2 pi f m_total``) and integral time [s].
    current_hz : float
        Current-loop bandwidth [Hz] (a first-order lag).
    speed_filter : float
        Time constant of the speed actual value's filter [s].
    travel : tuple of float
        Axis limits [m] (the part program is checked against them).
    """

    name: str
    kind: str = "rigid"
    screw: BallScrew = field(default_factory=BallScrew)
    rotor_inertia: float = 4.0e-3
    load_mass: float = 340.0
    carries_workpiece: bool = False
    gravity: bool = False
    motor_coulomb: float = 0.3
    motor_viscous: float = 2.0e-3
    load_coulomb: float = 150.0
    load_viscous: float = 800.0
    damping_ratio: float = 0.05
    torque_constant: float = 1.5
    peak_torque: float = 60.0
    encoder_counts: int = 2**22
    scale_resolution: float = 5e-9
    current_noise: float = 0.02
    current_lsb: float = 40.0 / 2**13
    kv: float = 50.0
    speed_hz: float = 40.0
    speed_ti: float = 0.010
    current_hz: float = 1600.0
    speed_filter: float = 0.2e-3
    travel: tuple[float, float] = (-0.1, 0.7)

    def __post_init__(self) -> None:
        if self.name not in ("X", "Y", "Z"):
            raise ParameterError("name", "one of ['X', 'Y', 'Z']", self.name)
        if self.kind not in ("rigid", "two_inertia"):
            raise ParameterError(f"{self.name}.kind", "'rigid' or 'two_inertia'", self.kind)
        for n in (
            "rotor_inertia",
            "load_mass",
            "torque_constant",
            "peak_torque",
            "kv",
            "speed_hz",
            "speed_ti",
            "current_hz",
            "speed_filter",
            "scale_resolution",
        ):
            require_positive(f"{self.name}.{n}", getattr(self, n))  # fmt: skip
        for n in (
            "motor_coulomb",
            "motor_viscous",
            "load_coulomb",
            "load_viscous",
            "current_noise",
            "current_lsb",
        ):
            require_nonnegative(f"{self.name}.{n}", getattr(self, n))  # fmt: skip
        require_in(f"{self.name}.damping_ratio", self.damping_ratio, 0.0, 1.0)
        if int(self.encoder_counts) != self.encoder_counts or self.encoder_counts < 256:
            raise ParameterError(
                f"{self.name}.encoder_counts", "an integer >= 256", self.encoder_counts
            )
        lo, hi = self.travel
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise ParameterError(f"{self.name}.travel", "finite (low, high), low < high", (lo, hi))

    @property
    def p(self) -> float:
        return self.screw.p

    @property
    def motor_mass(self) -> float:
        """Motor-side equivalent mass [kg]: rotor, coupling and screw over ``p^2``."""
        j = self.rotor_inertia + self.screw.coupling_inertia + self.screw.screw_inertia
        return j / self.p**2

    @property
    def stiffness(self) -> float:
        """Axial stiffness of the drive train [N/m]."""
        return self.screw.stiffness()

    @property
    def force_constant(self) -> float:
        """Motor force along the axis per ampere [N/A]."""
        return self.torque_constant / self.p

    @property
    def peak_force(self) -> float:
        return self.peak_torque / self.p

    def total_mass(self, workpiece: float = 0.0) -> float:
        return self.motor_mass + self.load(workpiece)

    def load(self, workpiece: float = 0.0) -> float:
        """Load-side mass [kg] with a workpiece of ``workpiece`` kg if it rides here."""
        return self.load_mass + (workpiece if self.carries_workpiece else 0.0)

    def mode_hz(self, workpiece: float = 0.0) -> tuple[float, float]:
        """First axial mode and the motor side's anti-resonance [Hz] (two-inertia)."""
        k, mm, ml = self.stiffness, self.motor_mass, self.load(workpiece)
        return (
            math.sqrt(k * (1.0 / mm + 1.0 / ml)) / (2.0 * math.pi),
            math.sqrt(k / ml) / (2.0 * math.pi),
        )

    def spring_damping(self, workpiece: float = 0.0) -> float:
        """Damping of the axial spring [N s/m] for :attr:`damping_ratio`."""
        mm, ml = self.motor_mass, self.load(workpiece)
        return 2.0 * self.damping_ratio * math.sqrt(self.stiffness * mm * ml / (mm + ml))

    def speed_gains(self, workpiece: float = 0.0) -> tuple[float, float]:
        """Speed-loop P gain [N/(m/s)] and I gain [N/m] for the crossover ``speed_hz``."""
        kp = 2.0 * math.pi * self.speed_hz * self.total_mass(workpiece)
        return kp, kp / self.speed_ti

    @property
    def encoder_quantum(self) -> float:
        """Motor encoder resolution along the axis [m]."""
        return self.screw.lead / self.encoder_counts


@dataclass(frozen=True)
class SpindleParams:
    """The spindle drive.

    Parameters
    ----------
    inertia : float
        Rotor, spindle shaft and tool holder [kg m^2].
    rated_torque, base_rpm, max_power, max_rpm : float
        Torque limit below the base speed [N m], the base speed [rpm], the power limit
        above it [W], the top speed [rpm].
    torque_constant : float
        Torque per ampere of torque-producing current [N m/A].
    coulomb, viscous : float
        Friction: Coulomb [N m] (warm), viscous [N m s/rad].
    warmup_share, warmup_time : float
        The Coulomb part is ``1 + warmup_share`` times higher cold and falls with
        ``warmup_time`` [s] of turning.
    speed_hz, speed_ti : float
        Speed-loop crossover [Hz] and integral time [s].
    ramp : float
        Acceleration of the speed command [rad/s^2] (the torque/power limits cap it).
    current_hz : float
        Current-loop bandwidth [Hz].
    speed_filter : float
        Time constant of the speed actual value's filter [s].
    power_smoothing : float
        Time constant of the CNC's power smoothing [s].
    current_noise : float
        Rms of the current measurement noise [A].
    """

    inertia: float = 0.035
    rated_torque: float = 95.0
    base_rpm: float = 1500.0
    max_power: float = 15_000.0
    max_rpm: float = 12_000.0
    torque_constant: float = 1.2
    coulomb: float = 0.5
    viscous: float = 4.0e-4
    warmup_share: float = 0.3
    warmup_time: float = 600.0
    speed_hz: float = 30.0
    speed_ti: float = 0.020
    ramp: float = 1500.0
    current_hz: float = 1600.0
    speed_filter: float = 1.0e-3
    power_smoothing: float = 0.010
    current_noise: float = 0.1

    def __post_init__(self) -> None:
        for n in (
            "inertia",
            "rated_torque",
            "base_rpm",
            "max_power",
            "max_rpm",
            "torque_constant",
            "warmup_time",
            "speed_hz",
            "speed_ti",
            "ramp",
            "current_hz",
            "speed_filter",
            "power_smoothing",
        ):
            require_positive(f"spindle.{n}", getattr(self, n))  # fmt: skip
        for n in ("coulomb", "viscous", "warmup_share", "current_noise"):
            require_nonnegative(f"spindle.{n}", getattr(self, n))
        if self.base_rpm >= self.max_rpm:
            raise ParameterError(
                "spindle.base_rpm", f"a speed < max_rpm {self.max_rpm:g}", self.base_rpm
            )

    def speed_gains(self) -> tuple[float, float]:
        """Speed-loop P gain [N m s/rad] and I gain [N m/rad]."""
        kp = 2.0 * math.pi * self.speed_hz * self.inertia
        return kp, kp / self.speed_ti

    def idle_torque(self, rpm: float, warm: bool = True) -> float:
        """Friction torque at a steady ``rpm`` [N m] (warm or cold)."""
        w = abs(rpm) * math.pi / 30.0
        c = self.coulomb * (1.0 if warm else 1.0 + self.warmup_share)
        return c + self.viscous * w

    def idle_power(self, rpm: float, warm: bool = True) -> float:
        """Power the spindle takes turning in the air at ``rpm`` [W]."""
        return self.idle_torque(rpm, warm) * abs(rpm) * math.pi / 30.0


def _x_axis() -> FeedAxisParams:
    return FeedAxisParams(
        name="X", kind="two_inertia", load_mass=340.0, carries_workpiece=True,
        travel=(-0.10, 0.70),
    )  # fmt: skip


def _y_axis() -> FeedAxisParams:
    # the saddle (350 kg) carries the X axis (its table, motor and screw: ~400 kg)
    return FeedAxisParams(
        name="Y", load_mass=750.0, carries_workpiece=True, load_coulomb=300.0,
        load_viscous=1500.0, travel=(-0.10, 0.40),
    )  # fmt: skip


def _z_axis() -> FeedAxisParams:
    # the spindle head with its motor; a 12 mm lead for the weight; the brake motor's rotor
    screw = BallScrew(lead=0.012, length=0.8, nut_distance=0.4)
    return FeedAxisParams(
        name="Z", screw=screw, rotor_inertia=5.0e-3, load_mass=400.0, gravity=True,
        load_coulomb=250.0, load_viscous=1200.0, travel=(-0.15, 0.40),
    )  # fmt: skip


@dataclass(frozen=True)
class CentreParams:
    """The whole machine: three feed axes, the spindle and the simulation rate.

    Parameters
    ----------
    x, y, z : FeedAxisParams
    spindle : SpindleParams
    sample_time : float
        The simulation's sample time [s] (default 100 us, 10 kHz).
    rapid, acceleration : float
        Rapid traverse speed [m/s] and the path acceleration limit [m/s^2] (no jerk
        limit: a step in acceleration, which excites the X axis' mode as a real
        unsmoothed move does).
    workpiece_density : float
        Of the blank [kg/m^3] (aluminium 6061).
    """

    x: FeedAxisParams = field(default_factory=_x_axis)
    y: FeedAxisParams = field(default_factory=_y_axis)
    z: FeedAxisParams = field(default_factory=_z_axis)
    spindle: SpindleParams = field(default_factory=SpindleParams)
    sample_time: float = 1.0 / SIM_RATE_HZ
    rapid: float = 0.5
    acceleration: float = 3.0
    workpiece_density: float = 2700.0

    def __post_init__(self) -> None:
        for name, ax in (("x", self.x), ("y", self.y), ("z", self.z)):
            if not isinstance(ax, FeedAxisParams) or ax.name != name.upper():
                raise ParameterError(name, f"a FeedAxisParams named {name.upper()!r}", ax)
        require_in("sample_time", self.sample_time, 2e-5, 5e-4)
        require_positive("rapid", self.rapid)
        require_positive("acceleration", self.acceleration)
        require_positive("workpiece_density", self.workpiece_density)

    @property
    def axes(self) -> tuple[FeedAxisParams, FeedAxisParams, FeedAxisParams]:
        return (self.x, self.y, self.z)

    @property
    def rate_hz(self) -> float:
        return 1.0 / self.sample_time

    def with_(self, **changes: object) -> CentreParams:
        return replace(self, **changes)  # type: ignore[arg-type]


__all__ = [
    "GRAVITY",
    "SIM_RATE_HZ",
    "BallScrew",
    "CentreParams",
    "FeedAxisParams",
    "SpindleParams",
]
