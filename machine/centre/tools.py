r"""The tool magazine: cutters, how they wear, and the state each tool keeps.

A :class:`MagazineTool` is :class:`machine.process.Tool` (flutes, diameter, helix,
runout, the linear edge-force law of seed003 (4)-(5) with the coefficients of
:mod:`machine.milling`) with what a machining centre adds: the axial force (the helix
pulls the tool down, the workpiece up), flank wear, and the tool's life.

Flank wear (a choice: the three phases of a milling cutter's wear curve, Taylor's
speed law). With :math:`T` the cutting time at the reference speed (time at another
speed counts :math:`(v/v_{ref})^{1/n}` times, Taylor's :math:`v T^n = C`, n = 0.25 for
carbide), and :math:`T_L` the tool's life at the reference speed:

.. math::

    VB(T) = VB_b\,(1 - e^{-T / (0.03 T_L)}) + r\,T + c\,(T/T_L)^6

break-in (:math:`VB_b` = 0.05 mm), steady wear (:math:`r T_L` = 0.18 mm) and the
accelerated end (:math:`c` = 0.07 mm), so that :math:`VB(T_L)` = 0.3 mm, the ISO 8688-2
criterion. Each new instance draws its life from a log-normal spread (``life_spread``,
1 sigma): tools of one kind do not all last as long.

Wear changes the force through the edge (rubbing) coefficients, which grow with the
flank land: :math:`K_{te} = K_{te,0} + c_{te} VB`, :math:`K_{re} = K_{re,0} + c_{re}
VB` (the land rubs mostly normal to the surface: :math:`c_{re} = 2 c_{te}`; with
:math:`c_{te}` = 100 N/mm^2 the tangential edge force grows by 30 N/mm at the limit,
about +50 % of the cutting power at a 0.05 mm chip). A CNC sees neither the width nor
the depth of a cut, so wear shows as the cutting power relative to the same tool's,
fresh, in the same block.

The default lives are short (minutes of cutting, ``life``): a real carbide end mill in
aluminium lasts hours, but a live session should see a tool wear out. Scale ``life``
for real time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from common.arrays import F64
from machine.errors import ParameterError, require_in, require_nonnegative, require_positive
from machine.process import Tool

#: ISO 8688-2's flank-wear criterion for end mills (uniform wear): VB = 0.3 mm
VB_LIMIT = 0.3e-3
#: the wear curve's shares of VB_LIMIT: break-in, steady, accelerated (sum 1)
_BREAK_IN, _STEADY, _ACCEL = 0.05e-3, 0.18e-3, 0.07e-3
#: break-in time constant over the life, exponent of the accelerated phase
_TAU_B, _ACCEL_EXP = 0.03, 6.0
#: most flutes a tool may have (the kernel's flute arrays)
MAX_FLUTES = 8


@dataclass(frozen=True)
class MagazineTool(Tool):
    """A cutter in the magazine.

    Parameters (beyond :class:`machine.process.Tool`)
    -------------------------------------------------
    name : str
        What a person calls it (shown with the tool number).
    k_ac, k_ae : float
        Axial cutting [N/m^2] and edge [N/m] coefficients (for aluminium: 220 N/mm^2 and
        1.5 N/mm, between the values reviewed for Al 6082-T6 and 7075-T6, Chinese J.
        Mech. Eng. 34 (2021), Table 5).
    c_te, c_re : float
        Growth of the tangential and radial edge coefficients per metre of flank land
        [N/m^2].
    life : float
        Cutting time to VB = 0.3 mm at ``ref_rpm`` [s].
    ref_rpm : float
        The speed at which ``life`` holds [rpm].
    taylor_n : float
        Taylor exponent.
    life_spread : float
        Log-normal spread (1 sigma) of a new instance's life.
    """

    name: str = "end mill"
    k_ac: float = 220e6
    k_ae: float = 1.5e3
    c_te: float = 100e6
    c_re: float = 200e6
    life: float = 600.0
    ref_rpm: float = 8000.0
    taylor_n: float = 0.25
    life_spread: float = 0.15

    def __post_init__(self) -> None:
        super().__post_init__()
        if not self.name or len(self.name) > 40:
            raise ParameterError(f"T{self.number}.name", "1-40 characters", self.name)
        for n in ("k_ac", "k_ae", "c_te", "c_re", "life_spread"):
            require_nonnegative(f"T{self.number}.{n}", getattr(self, n))
        for n in ("life", "ref_rpm"):
            require_positive(f"T{self.number}.{n}", getattr(self, n))
        require_in(f"T{self.number}.taylor_n", self.taylor_n, 0.05, 1.0)
        if self.eccentricity > 0.05 * self.diameter:
            raise ParameterError(
                f"T{self.number}.eccentricity", f"<= D/20 = {0.05 * self.diameter:g} m",
                self.eccentricity,
            )  # fmt: skip

    @property
    def radius(self) -> float:
        return 0.5 * self.diameter

    def speed_factor(self, rpm: float) -> float:
        """How much faster than at ``ref_rpm`` the tool wears at ``rpm`` (Taylor)."""
        return (abs(rpm) / self.ref_rpm) ** (1.0 / self.taylor_n)

    def coefficients(self, vb: float) -> F64:
        """``[k_tc, k_rc, k_te, k_re, k_ac, k_ae]`` with a flank land of ``vb`` [m]."""
        return np.array(
            [self.k_tc, self.k_rc, self.k_te + self.c_te * vb, self.k_re + self.c_re * vb,
             self.k_ac, self.k_ae]
        )  # fmt: skip


def flank_wear(t_eq: float, life: float) -> float:
    """Flank wear VB [m] after ``t_eq`` seconds of cutting at the reference speed, for a
    tool whose life there is ``life`` [s] (the module's three-phase curve)."""
    x = max(t_eq, 0.0) / life
    return _BREAK_IN * (1.0 - math.exp(-x / _TAU_B)) + _STEADY * x + _ACCEL * x**_ACCEL_EXP


@dataclass
class ToolState:
    """What one tool in the magazine keeps (mutable, copied with the machine's state).

    ``instance`` counts the instances mounted under this number (1: the first);
    ``t_eq`` the cutting time at the reference speed [s]; ``life`` this instance's life
    [s]; ``ecc``, ``ecc_deg`` its runout [m], [deg]; ``dr`` the radius each flute has
    lost [m] (a breakage); ``lost`` the share of its axial engagement gone (broken off
    or missing; 1: no tool); ``cut_time`` seconds it has cut.
    """

    number: int
    instance: int
    life: float
    ecc: float
    ecc_deg: float
    t_eq: float = 0.0
    cut_time: float = 0.0
    lost: float = 0.0
    dr: F64 = field(default_factory=lambda: np.zeros(MAX_FLUTES))

    def vb(self) -> float:
        """Flank wear now [m]."""
        return flank_wear(self.t_eq, self.life)

    @property
    def broken(self) -> bool:
        """A flute has lost radius or the tool part of its length."""
        return bool(np.any(self.dr != 0.0)) or self.lost > 0.0

    def copy(self) -> ToolState:
        return ToolState(
            self.number, self.instance, self.life, self.ecc, self.ecc_deg, self.t_eq,
            self.cut_time, self.lost, self.dr.copy(),
        )  # fmt: skip


def new_instance(
    tool: MagazineTool, rng: np.random.Generator | None, instance: int = 1
) -> ToolState:
    """A fresh instance of ``tool``: sharp, whole, its own life and runout.

    The first instance (``rng`` None) has the tool's nominal life and runout; later ones
    draw a life (log-normal, ``life_spread``) and a runout (0.5-1.5 times the nominal,
    any phase), as a new insert or a re-clamped cutter does.
    """
    if rng is None:
        return ToolState(tool.number, instance, tool.life, tool.eccentricity,
                         tool.eccentricity_deg)  # fmt: skip
    life = tool.life * math.exp(tool.life_spread * float(rng.standard_normal()))
    ecc = tool.eccentricity * float(rng.uniform(0.5, 1.5))
    return ToolState(tool.number, instance, life, ecc, float(rng.uniform(0.0, 360.0)))


__all__ = [
    "MAX_FLUTES",
    "VB_LIMIT",
    "MagazineTool",
    "ToolState",
    "flank_wear",
    "new_instance",
]
