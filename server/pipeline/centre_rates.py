"""Where the centre's trace rate lets the DFO and the eccentricity loop run, in numbers.

Issue 31 item 2 asks for the DFO following the measured spindle speed and the
eccentricity loop "where the rate allows (say where not)". Both look at the spindle's
orders: the DFO at the tooth-passing harmonics (``z`` flutes times the rotation), the
eccentricity tuner at the rotation itself (the runout's 1x) over each revolution. The
centre's trace is point samples at the position-control cycle with no anti-aliasing
beyond the drive's (docs/machining-centre.md): a frequency above the Nyquist frequency
does not vanish, it folds (:func:`alias`). :func:`tool_orders` lists, for each tool the
program cuts with, its speed, rotation and tooth-passing frequencies and where each lands
in the trace; :func:`dfo_reason` and :func:`eccentricity_reason` are the sentences the
parts give (``GET /api/machine``).
"""

from __future__ import annotations

from dataclasses import dataclass

from machine.centre.program import Program

__all__ = ["ToolOrders", "alias", "dfo_reason", "eccentricity_reason", "tool_orders"]


def alias(hz: float, rate_hz: float) -> float:
    """Where a frequency ``hz`` lands in point samples at ``rate_hz`` (0 .. rate/2)."""
    return abs(hz - rate_hz * round(hz / rate_hz))


@dataclass(frozen=True)
class ToolOrders:
    """A tool the program cuts with, at its programmed speed, seen by a trace."""

    tool: int
    flutes: int
    rpm: float
    rate_hz: float

    @property
    def rotation_hz(self) -> float:
        return self.rpm / 60.0

    @property
    def tooth_hz(self) -> float:
        return self.flutes * self.rotation_hz

    @property
    def samples_per_rev(self) -> float:
        return self.rate_hz / self.rotation_hz

    @property
    def tooth_seen(self) -> bool:
        """The tooth-passing frequency lies below the Nyquist frequency."""
        return self.tooth_hz < self.rate_hz / 2.0

    @property
    def tooth_alias_hz(self) -> float:
        return alias(self.tooth_hz, self.rate_hz)

    @property
    def max_rpm_for_tooth(self) -> float:
        """The highest speed whose tooth passing stays below the Nyquist frequency."""
        return 30.0 * self.rate_hz / self.flutes


def tool_orders(program: Program, rate_hz: float) -> list[ToolOrders]:
    """Each tool the program cuts with, at the highest speed it cuts at, in tool order."""
    top: dict[int, float] = {}
    for block, tool, rpm, _ in program.walk():
        if block.cut is not None and tool and rpm > 0.0:
            top[tool] = max(top.get(tool, 0.0), rpm)
    return [
        ToolOrders(t, program.tool(t).n_flutes, rpm, float(rate_hz))
        for t, rpm in sorted(top.items())
    ]


def _hz(x: float) -> str:
    return f"{x:.0f} Hz"


def dfo_reason(program: Program, rate_hz: float) -> str:
    """Why seed 002's DFO does not follow the centre's cut at ``rate_hz``, in numbers."""
    nyq = rate_hz / 2.0
    seen = [o for o in tool_orders(program, rate_hz) if o.tooth_seen]
    folded = [o for o in tool_orders(program, rate_hz) if not o.tooth_seen]
    said = [
        f"T{o.tool}'s tooth passing ({o.flutes} x {_hz(o.rotation_hz)} = {_hz(o.tooth_hz)} "
        f"at {o.rpm:.0f} rpm) lies below it"
        for o in seen
    ] + [
        f"T{o.tool}'s ({o.flutes} x {_hz(o.rotation_hz)} = {_hz(o.tooth_hz)} at {o.rpm:.0f} "
        f"rpm) folds to {_hz(o.tooth_alias_hz)} (below it up to {o.max_rpm_for_tooth:.0f} rpm)"
        for o in folded
    ]
    return (
        f"on this {rate_hz:.0f} Hz trace (Nyquist {_hz(nyq)}, point samples) "
        + "; ".join(said)
        + ": a DFO at the true harmonics sees only the tools whose tooth passing lies below "
        "the Nyquist frequency"
    )


def eccentricity_reason(program: Program, rate_hz: float) -> str:
    """Why seed 003's eccentricity loop does not run on the centre, in numbers."""
    orders = tool_orders(program, rate_hz)
    per_rev = ", ".join(
        f"T{o.tool} {o.samples_per_rev:.3g} at {o.rpm:.0f} rpm ({_hz(o.rotation_hz)})"
        for o in orders
    )
    onto = [o for o in orders if abs(o.tooth_alias_hz - o.rotation_hz) < 1.0]
    clash = "".join(
        f"; T{o.tool}'s tooth passing ({_hz(o.tooth_hz)}) folds onto its own 1x "
        f"({_hz(o.tooth_alias_hz)}): the runout cannot be told from the cut"
        for o in onto
    )
    return (
        "seed 003's tuner cancels the runout by commanding a circle on X and Y at the "
        "spindle's frequency, revolution by revolution: it acts on the CNC's position "
        "commands, and a trace is read-only (the loop simulates seed 003's milling "
        f"machine on the stage's scenario instead); its 1x on this {rate_hz:.0f} Hz trace "
        f"has {per_rev} samples per revolution{clash}"
    )
