"""A 3-axis machining centre with its spindle drive, exported as a CNC's trace (issue 31).

The machine (:mod:`machine.centre.params`: X a two-inertia ball-screw axis with a linear
scale, Y and Z semi-closed loop, Z against gravity; the spindle drive), its loops
(:mod:`machine.centre.loops`), its tools and their wear (:mod:`machine.centre.tools`), the
part program (:mod:`machine.centre.program`), the per-sample kernel
(:mod:`machine.centre.kernel`), the simulation (:mod:`machine.centre.sim`), the CNC's
trace (:mod:`machine.centre.trace`) and the signals' names in a machine description
(:mod:`machine.centre.signals`). Imports nothing of ours outside ``machine`` and
``common``.
"""

from machine.centre.params import BallScrew, CentreParams, FeedAxisParams, SpindleParams
from machine.centre.program import Block, Cut, Program, default_program, default_tools
from machine.centre.sim import CentreRecord, CentreState, MachiningCentre
from machine.centre.tools import VB_LIMIT, MagazineTool, ToolState, flank_wear
from machine.centre.trace import CncTrace, TraceParams, TraceRecord, TraceState

__all__ = [
    "VB_LIMIT",
    "BallScrew",
    "Block",
    "CentreParams",
    "CentreRecord",
    "CentreState",
    "CncTrace",
    "Cut",
    "FeedAxisParams",
    "MachiningCentre",
    "MagazineTool",
    "Program",
    "SpindleParams",
    "ToolState",
    "TraceParams",
    "TraceRecord",
    "TraceState",
    "default_program",
    "default_tools",
    "flank_wear",
]
