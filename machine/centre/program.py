r"""The part program of the machining centre: G-code blocks, tools, operations and parts.

A program is a list of blocks, each one G-code line with its number (N word):

``rapid`` (G0) and ``feed`` (G1)
    A straight move to ``target`` (X, Y, Z in the workpiece frame [m]) at the rapid
    speed or the programmed feed [m/s] times the feed override. A ``feed`` block may cut:
    its :class:`Cut` says the depth and width of the cut and which side the stock is on;
    the stock lies under the block's path (a cut block moves in the XY plane), and the
    engagement ramps in over one tool radius as the tool enters (``ramp_in``) and out as
    it leaves (``ramp_out``), as in :mod:`machine.process`. A contour's corner keeps the
    engagement (ramp off on both sides of it).
``tool_change`` (T.. M6)
    The spindle stops, the tool ``tool`` is put in it, ``seconds`` in all (the spindle's
    deceleration is part of it).
``spindle`` (S.. M3)
    The spindle runs up to ``rpm`` times the spindle override; the block ends when it is
    within 1 % of it (and after at least ``seconds``), as a CNC waits before feeding.
``dwell`` (G4) and ``end`` (M30)
    ``seconds`` without motion; ``end`` stops the spindle, and the next part's blank is
    clamped (``seconds``: the part change).

The interpolator (in the kernel) moves along each block with the path acceleration
limit, to an exact stop at its end (no look-ahead, no jerk limit); an override changes
the speed within the block, and an override of 0 (a feed hold) stops the axes where
they are.

:func:`default_program` is the part the live default machines: an aluminium blank
faced by a 50 mm face mill (T1, 3,000 rpm), two sides contoured by a 12 mm end mill (T2,
8,000 rpm), a slot by an 8 mm end mill (T3, 10,000 rpm); about 30 s per part.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from machine.centre.tools import MagazineTool
from machine.errors import ParameterError, require_in, require_nonnegative, require_positive
from machine.milling import check_rpm

#: block kinds
KINDS = ("rapid", "feed", "tool_change", "spindle", "dwell", "end")
#: the G/M words of each kind (for the G-code text)
_WORD = {"rapid": "G0", "feed": "G1", "dwell": "G4", "end": "M30"}


@dataclass(frozen=True)
class Cut:
    """The cut of a ``feed`` block (the CNC knows none of it: truth).

    ``axial_depth`` [m], ``radial_immersion`` (width over diameter, in (0, 1]),
    ``down_milling`` (the stock on the left of the feed direction, with the spindle
    turning as in :mod:`machine.milling`), ``ramp_in``/``ramp_out`` (the tool enters /
    leaves the stock in this block).
    """

    axial_depth: float
    radial_immersion: float
    down_milling: bool = False
    ramp_in: bool = True
    ramp_out: bool = True

    def __post_init__(self) -> None:
        require_positive("axial_depth", self.axial_depth)
        require_in("radial_immersion", self.radial_immersion, 0.0, 1.0, lo_open=True)

    def window(self) -> tuple[float, float]:
        """Entry and exit immersion angles relative to the feed direction (seed003 (5))."""
        r = self.radial_immersion
        if self.down_milling:
            return math.acos(2.0 * r - 1.0), math.pi
        return 0.0, math.acos(1.0 - 2.0 * r)


@dataclass(frozen=True)
class Block:
    """One G-code block (see the module docstring for the kinds)."""

    line: int
    kind: str
    target: tuple[float, float, float] | None = None
    feed: float = 0.0
    cut: Cut | None = None
    tool: int = 0
    rpm: float = 0.0
    seconds: float = 0.0
    comment: str = ""

    def __post_init__(self) -> None:
        where = f"line N{self.line}"
        if int(self.line) != self.line or self.line < 0:
            raise ParameterError("line", "a G-code line number >= 0", self.line)
        if self.kind not in KINDS:
            raise ParameterError(f"{where}.kind", f"one of {KINDS}", self.kind)
        moves = self.kind in ("rapid", "feed")
        if moves and (self.target is None or len(self.target) != 3
                      or not all(math.isfinite(v) for v in self.target)):  # fmt: skip
            raise ParameterError(f"{where}.target", "a finite (X, Y, Z) in m", self.target)
        if self.kind == "feed":
            require_positive(f"{where}.feed", self.feed)
        if self.cut is not None and self.kind != "feed":
            raise ParameterError(f"{where}.cut", "a cut only in a feed (G1) block", self.kind)
        if self.kind == "tool_change" and (int(self.tool) != self.tool or self.tool < 1):
            raise ParameterError(f"{where}.tool", "a tool number >= 1", self.tool)
        if self.kind == "spindle" and self.rpm != 0.0:
            check_rpm(self.rpm)
        require_nonnegative(f"{where}.seconds", self.seconds)

    def gcode(self) -> str:
        """The block as the CNC's G-code line (mm, mm/min)."""
        words = [f"N{self.line}"]
        if self.kind in ("rapid", "feed"):
            assert self.target is not None  # checked at construction
            words.append(_WORD[self.kind])
            words += [f"{a}{v * 1e3:.3f}" for a, v in zip("XYZ", self.target, strict=True)]
            if self.kind == "feed":
                words.append(f"F{self.feed * 6e4:.0f}")
        elif self.kind == "tool_change":
            words += [f"T{self.tool}", "M6"]
        elif self.kind == "spindle":
            words += [f"S{self.rpm:.0f}", "M3" if self.rpm > 0 else "M5"]
        elif self.kind == "dwell":
            words += ["G4", f"F{self.seconds:g}"]
        else:
            words.append("M30")
        if self.comment:
            words.append(f"({self.comment})")
        return " ".join(words)


@dataclass(frozen=True)
class Program:
    """A named program (O word), its blocks and the tools it calls.

    Checked at construction: every cut block has a tool in the spindle and the spindle
    running, moves in the XY plane only, and stays inside the axes' travel given by
    ``travel`` (per axis ``(low, high)`` [m], in the workpiece frame).
    """

    name: str
    blocks: tuple[Block, ...]
    tools: tuple[MagazineTool, ...]
    start: tuple[float, float, float] = (0.0, 0.0, 0.2)

    def __post_init__(self) -> None:
        if not self.name or len(self.name) > 32:
            raise ParameterError("name", "a program name of 1-32 characters", self.name)
        if not self.blocks:
            raise ParameterError("blocks", "at least one block", 0)
        lines = [b.line for b in self.blocks]
        if len(set(lines)) != len(lines):
            raise ParameterError("blocks", "unique line numbers", lines)
        numbers = [t.number for t in self.tools]
        if len(set(numbers)) != len(numbers):
            raise ParameterError("tools", "unique tool numbers", numbers)
        self.walk()

    def tool(self, number: int) -> MagazineTool:
        for t in self.tools:
            if t.number == number:
                return t
        raise ParameterError("tool", f"one of {[t.number for t in self.tools]}", number)

    def walk(self) -> list[tuple[Block, int, float, tuple[float, float, float]]]:
        """Each block with the tool in the spindle, the spindle speed and the start point
        of its move (checked as it goes)."""
        tool, rpm, pos = 0, 0.0, self.start
        out = []
        for b in self.blocks:
            where = f"line N{b.line}"
            if b.kind == "tool_change":
                self.tool(b.tool)
            out.append((b, tool, rpm, pos))
            if b.kind == "tool_change":
                tool, rpm = b.tool, 0.0
            elif b.kind == "spindle":
                rpm = b.rpm
            elif b.kind == "end":
                rpm = 0.0
            if b.cut is not None:
                assert b.target is not None
                if tool == 0 or rpm <= 0.0:
                    raise ParameterError(f"{where}.cut", "a tool in the spindle, turning",
                                         f"tool {tool}, {rpm:g} rpm")  # fmt: skip
                if abs(b.target[2] - pos[2]) > 1e-12:
                    raise ParameterError(f"{where}.target", "a cut in the XY plane (Z held)",
                                         b.target)  # fmt: skip
            if b.target is not None:
                pos = b.target
        return out

    def gcode(self) -> list[str]:
        """The program as G-code lines."""
        return [f"O{self.name.lstrip('O')}", *(b.gcode() for b in self.blocks)]

    def line_text(self, line: int) -> str:
        """The G-code of line ``line``."""
        for b in self.blocks:
            if b.line == line:
                return b.gcode()
        raise ParameterError("line", f"one of {[b.line for b in self.blocks]}", line)


def feed_for(tool: MagazineTool, rpm: float, feed_per_tooth: float) -> float:
    """The feed rate [m/s] for a feed per tooth [m] at ``rpm``."""
    return feed_per_tooth * tool.n_flutes * rpm / 60.0


def default_tools() -> tuple[MagazineTool, MagazineTool, MagazineTool]:
    """T1 face mill 50 mm (4 inserts), T2 end mill 12 mm (3 flutes), T3 end mill 8 mm
    (2 flutes), carbide for aluminium; lives of 4-10 minutes of cutting (accelerated)."""
    t1 = MagazineTool(number=1, name="face mill D50", n_flutes=4, diameter=50e-3,
                      helix_deg=0.0, eccentricity=10e-6, eccentricity_deg=40.0,
                      k_ac=80e6, life=300.0, ref_rpm=3000.0)  # fmt: skip
    t2 = MagazineTool(number=2, name="end mill D12", n_flutes=3, diameter=12e-3,
                      helix_deg=35.0, eccentricity=6e-6, eccentricity_deg=200.0,
                      life=400.0, ref_rpm=8000.0)  # fmt: skip
    t3 = MagazineTool(number=3, name="end mill D8", n_flutes=2, diameter=8e-3,
                      helix_deg=30.0, eccentricity=5e-6, eccentricity_deg=120.0,
                      life=240.0, ref_rpm=10000.0)  # fmt: skip
    return t1, t2, t3


def default_program(name: str = "O2001", *, rpm_scale: float = 1.0) -> Program:
    """The default part (see the module docstring): a 100 x 60 x 40 mm aluminium blank,
    its top at Z = 0, its corner at X = Y = 0. ``rpm_scale`` scales every spindle speed
    (the feeds with them: the feed per tooth is held), in (0.5, 1.2]."""
    require_in("rpm_scale", rpm_scale, 0.5, 1.2, lo_open=True)
    t1, t2, t3 = default_tools()
    r = rpm_scale
    mm = 1e-3
    home = 200 * mm

    def p(x: float, y: float, z: float) -> tuple[float, float, float]:
        return (x * mm, y * mm, z * mm)

    f1 = feed_for(t1, 3000 * r, 0.20 * mm)
    f2 = feed_for(t2, 8000 * r, 0.06 * mm)
    f3 = feed_for(t3, 10000 * r, 0.04 * mm)
    plunge = 2000 * mm / 60.0
    face = Cut(1.5 * mm, 0.7)
    side1 = Cut(10 * mm, 0.25, down_milling=True, ramp_out=False)
    side2 = Cut(10 * mm, 0.25, down_milling=True, ramp_in=False)
    slot = Cut(3 * mm, 1.0, ramp_out=False)
    blocks = (
        Block(10, "tool_change", tool=1, seconds=2.0, comment="face mill D50"),
        Block(20, "spindle", rpm=3000.0 * r, seconds=0.2),
        Block(30, "rapid", p(-40, 50, 20)),
        Block(40, "feed", p(-40, 50, -1.5), feed=plunge),
        Block(50, "feed", p(-25, 50, -1.5), feed=f1),
        Block(60, "feed", p(125, 50, -1.5), feed=f1, cut=face, comment="face"),
        Block(70, "rapid", p(125, 50, 50)),
        Block(100, "tool_change", tool=2, seconds=2.0, comment="end mill D12"),
        Block(110, "spindle", rpm=8000.0 * r, seconds=0.2),
        Block(120, "rapid", p(-12, -3, 20)),
        Block(130, "feed", p(-12, -3, -10), feed=plunge),
        Block(135, "feed", p(-6, -3, -10), feed=f2),
        Block(140, "feed", p(103, -3, -10), feed=f2, cut=side1, comment="side Y0"),
        Block(150, "feed", p(103, 66, -10), feed=f2, cut=side2, comment="side X100"),
        Block(160, "rapid", p(103, 66, 50)),
        Block(200, "tool_change", tool=3, seconds=2.0, comment="end mill D8"),
        Block(210, "spindle", rpm=10000.0 * r, seconds=0.2),
        Block(220, "rapid", p(50, -10, 20)),
        Block(230, "feed", p(50, -10, -3), feed=plunge),
        Block(240, "feed", p(50, -4, -3), feed=f3),
        Block(250, "feed", p(50, 36, -3), feed=f3, cut=slot, comment="slot"),
        Block(260, "rapid", p(50, 36, 50)),
        Block(270, "rapid", (0.0, 0.0, home)),
        Block(280, "end", seconds=3.0, comment="part change"),
    )
    return Program(name, blocks, (t1, t2, t3), start=(0.0, 0.0, home))


#: the spindle-speed scales of :func:`program_variant`, in turn
VARIANT_SCALES = (1.0, 0.9, 1.1, 0.8, 1.05, 0.95)


def program_variant(k: int) -> Program:
    """Machine ``k``'s program in a plant: the default part as ``O{2001 + k}``, its spindle
    speeds scaled by :data:`VARIANT_SCALES` in turn (other tooth frequencies, other
    folds in a trace)."""
    if int(k) != k or k < 0:
        raise ParameterError("k", "a machine index >= 0", k)
    return default_program(
        f"O{2001 + int(k)}", rpm_scale=VARIANT_SCALES[int(k) % len(VARIANT_SCALES)]
    )


def blank_mass(density: float) -> float:
    """Mass of the default blank, 100 x 60 x 40 mm [kg]."""
    return density * 0.100 * 0.060 * 0.040


__all__ = [
    "KINDS",
    "Block",
    "Cut",
    "Program",
    "blank_mass",
    "default_program",
    "default_tools",
    "feed_for",
    "program_variant",
]
