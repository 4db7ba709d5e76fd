r"""Part programs with identities, and the process events a monitor must catch.

The machine is seed 003's spindle on its X/Y feed drives (:mod:`machine.milling`,
:mod:`machine.feed_drives`), now running a *part program*: blocks of cuts and air moves,
each with its G-code line and tool, a tool change between operations, parts one after
another, feed overrides now and then, and tool wear going on. Into this run the simulator
injects the events a process monitor is bought for, and keeps their truth (time, kind,
size) beside the measurements:

``breakage``
    One flute loses part of its edge: its radius drops by ``size`` [m]. The chip of every
    flute is the smaller of the two surfaces left by the previous flute and the one before
    (the runout chip of Kline & DeVor, seed003 (4) extended two flutes back):
    :math:`h_j = \min_{m=1,2}(\,\Delta P(m\tau)\cdot n(\phi) + r_j - r_{j-m})`. A loss larger
    than the feed per tooth is a broken tooth (no chip for that flute, a double chip for the
    next one: a once-per-revolution force pattern); a smaller one is a chipped edge.
``collision``
    A force far beyond the process's: the path speed jumps to ``size`` times the programmed
    feed in a cut (a feed far too high, a rapid into stock).
``missing_tool``
    The tool is missing or broken off: a fraction ``size`` of its axial engagement is gone
    (1: no cutting at all where the program cuts).

Everything here is the truth side: the detectors see only the drive signals
(currents, positions, spindle angle) and the CNC's identities (tool, program, line,
feed override).

Workpiece geometry (a choice): every block moves along X. A cut block's stock spans its
path, so the engagement (a factor on the axial depth) ramps in over one tool radius as
the tool centre enters and out as it leaves.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np
from numba import njit

from common.arrays import F64
from common.event_kinds import ProcessEventKind
from machine.errors import ParameterError, require_in, require_nonnegative, require_positive
from machine.feed_drives import FeedDriveParams
from machine.milling import check_rpm, drive_step

#: event kinds the simulator injects
#: the kinds of event the simulator injects (:class:`common.event_kinds.ProcessEventKind`)
EVENT_KINDS: tuple[ProcessEventKind, ...] = tuple(ProcessEventKind)
#: per-sample output rows of :func:`_process_kernel`
_ROWS = ("fx", "fy", "x", "y", "ix", "iy", "psi", "engaged")


@dataclass(frozen=True)
class Tool:
    """A cutter in the magazine (one tool number), and how it wears.

    Parameters
    ----------
    number : int
        Tool number (T word), >= 1.
    n_flutes, diameter, helix_deg : int, float, float
        As :class:`machine.milling.MillingParams`.
    eccentricity, eccentricity_deg : float
        Runout of the mounted instance [m], [deg] (seed003 (6)).
    k_tc, k_rc, k_te, k_re : float
        Cutting and edge coefficients of the sharp tool [N/m^2], [N/m].
    wear_per_s : float
        Growth of the edge coefficients per second of cutting (a fraction): flank wear
        rubs, so the edge force grows (a choice standing in for seed 004's wear law).
    wear_limit : float
        Edge-coefficient growth at which the tool is replaced by a fresh instance.
    """

    number: int = 1
    n_flutes: int = 4
    diameter: float = 10e-3
    helix_deg: float = 30.0
    eccentricity: float = 8e-6
    eccentricity_deg: float = 40.0
    k_tc: float = 700e6
    k_rc: float = 210e6
    k_te: float = 20e3
    k_re: float = 25e3
    wear_per_s: float = 2e-3
    wear_limit: float = 1.0

    def __post_init__(self) -> None:
        if int(self.number) != self.number or self.number < 1:
            raise ParameterError("number", "a tool number >= 1", self.number)
        if int(self.n_flutes) != self.n_flutes or not 1 <= self.n_flutes <= 8:
            raise ParameterError("n_flutes", "an integer in [1, 8]", self.n_flutes)
        require_positive("diameter", self.diameter)
        require_in("helix_deg", self.helix_deg, 0.0, 60.0)
        require_nonnegative("eccentricity", self.eccentricity)
        for name in ("k_tc", "k_rc", "k_te", "k_re", "wear_per_s", "wear_limit"):
            require_nonnegative(name, getattr(self, name))


@dataclass(frozen=True)
class ProgramBlock:
    """One G-code block: a straight move along X, cutting or in the air.

    Parameters
    ----------
    line : int
        The G-code line (N word) the CNC reports.
    tool : int
        Tool number in the spindle.
    cut : bool
        A cut (the stock is under the path) or an air move.
    length : float
        Path length [m].
    spindle_rpm : float
        Spindle speed [rpm].
    feed_per_tooth : float
        Programmed feed per tooth [m] (cuts); air moves go at ``air_speed``.
    axial_depth, radial_immersion : float
        Cut geometry (cuts only).
    down_milling : bool
        Climb milling.
    air_speed : float
        Path speed of an air move [m/s].
    """

    line: int
    tool: int
    cut: bool
    length: float
    spindle_rpm: float = 1200.0
    feed_per_tooth: float = 60e-6
    axial_depth: float = 1e-3
    radial_immersion: float = 0.3
    down_milling: bool = False
    air_speed: float = 0.02

    def __post_init__(self) -> None:
        if int(self.line) != self.line or self.line < 0:
            raise ParameterError("line", "a G-code line number >= 0", self.line)
        require_positive("length", self.length)
        check_rpm(self.spindle_rpm)
        require_positive("feed_per_tooth", self.feed_per_tooth)
        require_positive("axial_depth", self.axial_depth)
        require_in("radial_immersion", self.radial_immersion, 0.0, 1.0, lo_open=True)
        require_positive("air_speed", self.air_speed)


@dataclass(frozen=True)
class PartProgram:
    """A named program (O word) of blocks, and the tools it calls."""

    name: str
    blocks: tuple[ProgramBlock, ...]
    tools: tuple[Tool, ...]

    def __post_init__(self) -> None:
        if not self.name or len(self.name) > 32:
            raise ParameterError("name", "a program name of 1-32 characters", self.name)
        if not self.blocks:
            raise ParameterError("blocks", "at least one block", 0)
        have = {t.number for t in self.tools}
        for b in self.blocks:
            if b.tool not in have:
                raise ParameterError(
                    f"blocks[line {b.line}].tool", f"one of {sorted(have)}", b.tool
                )

    def tool(self, number: int) -> Tool:
        for t in self.tools:
            if t.number == number:
                return t
        raise ParameterError("tool", f"one of {[t.number for t in self.tools]}", number)


@dataclass(frozen=True)
class ProcessEvent:
    """An event to inject: where in the run, what and how large.

    Parameters
    ----------
    kind : str
        One of :data:`EVENT_KINDS`.
    part : int
        Part index (0-based) in which it happens.
    line : int
        G-code line of the block in which it happens.
    fraction : float
        Where in that block (share of its samples), in [0, 1).
    size : float
        ``breakage``: radius lost by the flute [m]; ``collision``: feed multiplier (> 1);
        ``missing_tool``: share of the axial engagement lost, in (0, 1].
    flute : int
        Flute that breaks (``breakage``).
    """

    kind: str
    part: int
    line: int
    fraction: float = 0.5
    size: float = 1.0
    flute: int = 0

    def __post_init__(self) -> None:
        if self.kind not in EVENT_KINDS:
            raise ParameterError("kind", "one of " + ", ".join(EVENT_KINDS), self.kind)
        if int(self.part) != self.part or self.part < 0:
            raise ParameterError("part", "a part index >= 0", self.part)
        require_in("fraction", self.fraction, 0.0, 1.0, hi_open=True)
        require_positive("size", self.size)
        if self.kind == ProcessEventKind.COLLISION and self.size <= 1.0:
            raise ParameterError("size", "a feed multiplier > 1 for a collision", self.size)
        if self.kind == ProcessEventKind.MISSING_TOOL and self.size > 1.0:
            raise ParameterError("size", "a share in (0, 1] for a missing tool", self.size)


@dataclass(frozen=True)
class EventTruth:
    """What happened, for scoring only (never given to a detector)."""

    kind: str
    t: float
    sample: int
    size: float
    tool: int
    line: int
    part: int


@dataclass
class BlockRecord:
    """One executed program block: drive signals, identities and the truth beside them.

    Drive side (what a CNC's data interface gives): ``t`` [s], ``x, y`` carriage positions
    [m] (unquantised here; the observer quantises), ``ix, iy`` motor currents [A], ``psi``
    spindle angle [rad], ``tool``, ``program``, ``line``, ``override`` (feed override, 1 =
    100 %), ``k0`` the index of the first sample in the run.
    Truth side: ``fx, fy`` force on the workpiece [N], ``engaged`` engagement factor,
    ``wear`` edge-coefficient growth, ``events`` injected in this block.
    """

    k0: int
    t: F64
    x: F64
    y: F64
    ix: F64
    iy: F64
    psi: F64
    tool: int
    program: str
    line: int
    part: int
    override: float
    spindle_rpm: float
    cut: bool
    fx: F64
    fy: F64
    engaged: F64
    wear: float
    events: list[EventTruth] = field(default_factory=list)

    @property
    def n(self) -> int:
        return len(self.t)


class ProcessCut(NamedTuple):
    """A program block's cut as the kernel takes it (read only over a block)."""

    ts: float  # sample time [s]
    nf: int  # flutes
    lags: F64  # each axial layer's lag [rad] (helix)
    dz: float  # layer height [m]
    phi_st: float  # immersion window: start [rad]
    phi_ex: float  # and exit [rad]
    kc: F64  # [K_tc, K_rc, K_te, K_re]
    ecc: float  # eccentricity [m]
    ecc_phase: float  # its angle [rad]
    omega: float  # spindle speed [rad/s]
    v_target: float  # path speed target [m/s]
    acc: float  # path acceleration limit [m/s^2]
    stock: F64  # [x_in, x_out, ramp, cut]: the stock's edges along the path, the ramp [m]
    a_m: float  # the modulation circle (seed003 (7)): radius [m]
    theta_m: float  # and phase [rad]


class ProcessChange(NamedTuple):
    """What an event changes from its sample on (none: ``k_ev`` past the block)."""

    k_ev: int  # the event's first sample in the block
    dr0: F64  # the flutes' radius offsets before it [m]
    dr1: F64  # and from it on
    feed_mul: float  # the path speed target's factor from it on
    depth_after: float  # the engagement's factor from it on


@njit(cache=True)
def _process_kernel(n, cut, change, drive, st, ax, hist, out):  # pragma: no cover
    """Advance ``n`` samples of one block.

    ``cut`` (:class:`ProcessCut`) the block's cut, ``drive`` the drives' packed design;
    ``st = [psi, path_x, head, path_v]``; ``ax[i] = [x, v, integral, e_prev]``; ``hist``
    ring buffer of tool-centre positions; ``cut.stock = [x_in, x_out, ramp, cut]`` the
    stock's edges along the path and the engagement ramp length [m]. From sample
    ``change.k_ev`` on (:class:`ProcessChange`), the flute radius offsets are ``dr1``
    (before: ``dr0``), the path speed target is multiplied by ``feed_mul`` and the
    engagement by ``depth_after``.
    """
    ts, nf, lags, dz, phi_st, phi_ex, kc = (
        cut.ts, cut.nf, cut.lags, cut.dz, cut.phi_st, cut.phi_ex, cut.kc
    )  # fmt: skip
    ecc, ecc_phase, omega, v_target, acc = cut.ecc, cut.ecc_phase, cut.omega, cut.v_target, cut.acc
    stock, a_m, theta_m = cut.stock, cut.a_m, cut.theta_m
    k_ev, dr0, dr1, feed_mul, depth_after = change
    hlen = hist.shape[0]
    two_pi = 2.0 * math.pi
    pitch = two_pi / nf
    lag1 = pitch / omega / ts
    for k in range(n):
        after = k >= k_ev
        dr = dr1 if after else dr0
        vt = v_target * (feed_mul if after else 1.0)
        # path speed: rate-limited toward the target (a CNC's acceleration limit), but a
        # collision's jump is a step (the axes are driven into the stock at once)
        v = st[3]
        if after and feed_mul != 1.0:
            v = vt
        elif v < vt:
            v = min(vt, v + acc * ts)
        else:
            v = max(vt, v - acc * ts)
        st[3] = v
        psi = st[0]
        # seed003 (7): the modulation circle on the position command
        rx = st[1] + a_m * math.cos(psi + theta_m)
        ry = a_m * math.sin(psi + theta_m)
        # seed003 (6): geometric tool centre = carriage + eccentricity
        px = ax[0, 0] + ecc * math.cos(psi + ecc_phase)
        py = ax[1, 0] + ecc * math.sin(psi + ecc_phase)
        head = int(st[2])
        hist[head, 0] = px
        hist[head, 1] = py
        # engagement: the stock under the tool centre, ramped over one diameter
        e = 0.0
        if stock[3] > 0.0:
            e = min(max((ax[0, 0] - stock[0]) / stock[2], 0.0), 1.0)
            e = min(e, min(max((stock[1] - ax[0, 0]) / stock[2], 0.0), 1.0))
            if after:
                e *= depth_after
        fx = 0.0
        fy = 0.0
        if e > 0.0:
            # tool centre one and two tooth periods ago
            d1x = 0.0
            d1y = 0.0
            d2x = 0.0
            d2y = 0.0
            for m in range(1, 3):
                back = m * lag1
                i0 = math.floor(back)
                fr = back - i0
                ia = (head - i0) % hlen
                ib = (head - i0 - 1) % hlen
                qx = (1.0 - fr) * hist[ia, 0] + fr * hist[ib, 0]
                qy = (1.0 - fr) * hist[ia, 1] + fr * hist[ib, 1]
                if m == 1:
                    d1x = px - qx
                    d1y = py - qy
                else:
                    d2x = px - qx
                    d2y = py - qy
            p0 = psi % two_pi
            dze = dz * e
            for j in range(nf):
                jm1 = (j - 1) % nf
                jm2 = (j - 2) % nf
                for li in range(lags.shape[0]):
                    # seed003 (1): immersion of flute j, layer l
                    phi = p0 - j * pitch - lags[li]
                    while phi < 0.0:
                        phi += two_pi
                    # seed003 (5): the window
                    if phi < phi_st or phi > phi_ex:
                        continue
                    s = math.sin(phi)
                    c = math.cos(phi)
                    # seed003 (4) with the surfaces of the last two flutes (runout chip):
                    # h = min over m of dP(m tau).n(phi) + r_j - r_{j-m}
                    h1 = d1x * s - d1y * c + dr[j] - dr[jm1]
                    h2 = d2x * s - d2y * c + dr[j] - dr[jm2]
                    h = min(h1, h2)
                    if h <= 0.0:
                        continue
                    ft = kc[0] * dze * h + kc[2] * dze
                    fr_ = kc[1] * dze * h + kc[3] * dze
                    fx += ft * c + fr_ * s
                    fy += ft * s - fr_ * c
        out[0, k] = fx
        out[1, k] = fy
        out[2, k] = ax[0, 0]
        out[3, k] = ax[1, 0]
        out[6, k] = psi
        out[7, k] = e
        for i in range(2):
            out[4 + i, k] = drive_step(drive, ax, i, rx if i == 0 else ry, fx if i == 0 else fy, ts)
        st[0] = psi + omega * ts
        st[1] += v * ts
        st[2] = (head + 1) % hlen


@dataclass
class BlockRun:
    """A program block under way (:meth:`ProcessMachine.begin_block`): what its kernel
    needs, how far it has run, and the event placed in it (``k_ev``: its first sample in
    the block; past the end when none)."""

    blk: ProgramBlock
    tool: Tool
    override: float
    n_total: int
    k_start: int
    part: int
    k_ev: int
    dr0: F64
    dr1: F64
    stock: F64
    phi_st: float
    phi_ex: float
    lags: F64
    dz: float
    kc: F64
    omega: float
    v_target: float
    wear: float
    feed_mul: float = 1.0
    depth_after: float = 1.0
    done: int = 0
    event: str = ""
    truth: list[EventTruth] = field(default_factory=list)

    @property
    def left(self) -> int:
        """Samples still to run."""
        return self.n_total - self.done


@dataclass
class _ToolInstance:
    tool: Tool
    ecc: float
    ecc_deg: float
    wear: float = 0.0
    dr: F64 = field(default_factory=lambda: np.zeros(8))


class ProcessMachine:
    """Seed 003's milling machine running a part program, with events injected.

    Parameters
    ----------
    program : PartProgram
        The program run part after part.
    drives : FeedDriveParams
        The feed drives (5 kHz by default).
    rng : numpy.random.Generator
        Draws the variation the shop adds: overrides, workpiece depth, new tool instances'
        runout.
    override_prob : float
        Chance per part of a feed override other than 100 % (drawn from 80-120 %).
    depth_spread : float
        Relative spread (1 sigma) of the axial depth from one workpiece to the next.
    n_layers : int
        Axial layers of seed003 (1).
    events : list of ProcessEvent
        Events to inject.

    Examples
    --------
    >>> m = ProcessMachine(default_program(), rng=np.random.default_rng(0))
    >>> blocks = m.run_part()
    """

    def __init__(
        self,
        program: PartProgram,
        *,
        drives: FeedDriveParams | None = None,
        rng: np.random.Generator | None = None,
        override_prob: float = 0.2,
        depth_spread: float = 0.02,
        n_layers: int = 6,
        events: list[ProcessEvent] | None = None,
    ) -> None:
        self.program = program
        self.drives = drives if drives is not None else FeedDriveParams()
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.override_prob = require_in("override_prob", override_prob, 0.0, 1.0)
        self.depth_spread = require_nonnegative("depth_spread", depth_spread)
        if int(n_layers) != n_layers or not 1 <= n_layers <= 50:
            raise ParameterError("n_layers", "an integer in [1, 50]", n_layers)
        self.n_layers = int(n_layers)
        self.events = list(events or [])
        self._drive = self.drives.packed()
        ts = self.sample_time
        min_tooth = min(
            60.0 / (b.spindle_rpm * program.tool(b.tool).n_flutes) for b in program.blocks
        )
        self._min_tooth = min_tooth
        max_tooth = max(
            60.0 / (b.spindle_rpm * program.tool(b.tool).n_flutes) for b in program.blocks
        )
        self._hlen = math.ceil(2.0 * max_tooth / ts) + 8
        self.modulation = (0.0, 0.0)
        self.reset()

    @property
    def sample_time(self) -> float:
        return self.drives.sample_time

    @property
    def t(self) -> float:
        return self.k * self.sample_time

    def reset(self) -> None:
        """Start over: parts from 0, fresh tools, the carriage at rest."""
        self.k = 0
        self.part = 0
        self.st = np.zeros(4)
        self.ax = np.zeros((2, 4))
        self.hist = np.zeros((self._hlen, 2))
        self.instances = {t.number: self._new_instance(t, first=True) for t in self.program.tools}
        self.tool_changes = 0
        self.broken: frozenset[int] = frozenset()

    def _new_instance(self, tool: Tool, *, first: bool = False) -> _ToolInstance:
        if first:
            return _ToolInstance(tool, tool.eccentricity, tool.eccentricity_deg)
        # a fresh instance of the same tool number: another runout
        ecc = tool.eccentricity * float(self.rng.uniform(0.5, 1.5))
        return _ToolInstance(tool, ecc, float(self.rng.uniform(0.0, 360.0)))

    def replace_tool(self, number: int) -> None:
        """Mount a fresh instance of tool ``number`` (sharp, whole flutes, another runout):
        the operator's tool change after a breakage or a lost tool."""
        tool = self.program.tool(number)
        self.instances[tool.number] = self._new_instance(tool)
        self.tool_changes += 1

    def set_modulation(self, a_m: float, theta_m: float) -> None:
        """The circle of seed003 (7) on the position command (the eccentricity canceller's
        output), held until changed."""
        if not (math.isfinite(a_m) and math.isfinite(theta_m)) or abs(a_m) > 100e-6:
            raise ParameterError("a_m", "a finite radius <= 100e-6 m", a_m)
        self.modulation = (float(a_m), float(theta_m))

    def begin_part(self) -> tuple[float, float]:
        """The shop's draws for the next part: its feed override and workpiece depth scale."""
        override = 1.0
        if self.rng.random() < self.override_prob:
            override = float(self.rng.choice([0.8, 0.9, 1.1, 1.2]))
        depth_scale = 1.0 + self.depth_spread * float(self.rng.standard_normal())
        return override, depth_scale

    def run_part(self) -> list[BlockRecord]:
        """Run the whole program once (one part); the next call cuts the next part."""
        out = []
        override, depth_scale = self.begin_part()
        for blk in self.program.blocks:
            out.extend(self.run_block(blk, override=override, depth_scale=depth_scale))
        self.part += 1
        return out

    def block_samples(self, blk: ProgramBlock, override: float = 1.0) -> int:
        """Samples the block takes at its programmed speed (acceleration ignored)."""
        return max(1, round(blk.length / (self._speed(blk) * override) / self.sample_time))

    def _speed(self, blk: ProgramBlock) -> float:
        if not blk.cut:
            return blk.air_speed
        tool = self.program.tool(blk.tool)
        return blk.feed_per_tooth * tool.n_flutes * blk.spindle_rpm / 60.0

    def run_block(
        self,
        blk: ProgramBlock,
        *,
        override: float = 1.0,
        depth_scale: float = 1.0,
        chunk: int = 0,
        on_chunk: Callable[[BlockRecord], None] | None = None,
    ) -> list[BlockRecord]:
        """Run one block (in chunks of ``chunk`` samples if > 0, else in one record).

        ``on_chunk`` is called with each chunk's record before the next chunk runs (a
        controller there may change :meth:`set_modulation` for the next chunk).
        """
        run = self.begin_block(blk, override=override, depth_scale=depth_scale)
        step = run.n_total if chunk <= 0 else int(chunk)
        recs = []
        while run.left > 0:
            recs.append(self.advance(run, step))
            if on_chunk is not None:
                on_chunk(recs[-1])
        self.end_block(run)
        return recs

    def begin_block(
        self, blk: ProgramBlock, *, override: float = 1.0, depth_scale: float = 1.0
    ) -> BlockRun:
        """Start one block: a resumable :class:`BlockRun` that :meth:`advance` steps in any
        chunks and :meth:`end_block` closes (the event of :attr:`events` for this part and
        line, if any, is placed in it)."""
        inst = self.instances[blk.tool]
        tool = inst.tool
        n_total = self.block_samples(blk, override)
        ev = [e for e in self.events if e.part == self.part and e.line == blk.line]
        if len(ev) > 1:
            raise ParameterError("events", "at most one event per part and block", len(ev))
        if blk.cut:
            x0 = self.st[1]
            ramp = 0.5 * tool.diameter
            stock = np.array([x0, x0 + blk.length, ramp, 1.0])
        else:
            stock = np.zeros(4)
        imm = blk.radial_immersion
        phi_st, phi_ex = (
            (math.acos(2.0 * imm - 1.0), math.pi)
            if blk.down_milling
            else (0.0, math.acos(1.0 - 2.0 * imm))
        )
        z = (np.arange(self.n_layers) + 0.5) * blk.axial_depth / self.n_layers
        lags = 2.0 * z * math.tan(math.radians(tool.helix_deg)) / tool.diameter
        wear = inst.wear
        kc = np.array([tool.k_tc, tool.k_rc, tool.k_te * (1 + wear), tool.k_re * (1 + wear)])
        dr0 = inst.dr[: tool.n_flutes].copy()
        run = BlockRun(
            blk=blk,
            tool=tool,
            override=override,
            n_total=n_total,
            k_start=self.k,
            part=self.part,
            k_ev=n_total + 1,
            dr0=dr0,
            dr1=dr0.copy(),
            stock=stock,
            phi_st=phi_st,
            phi_ex=phi_ex,
            lags=lags,
            dz=blk.axial_depth * depth_scale / self.n_layers,
            kc=kc,
            omega=2.0 * math.pi * blk.spindle_rpm / 60.0,
            v_target=self._speed(blk) * (override if blk.cut else 1.0),
            wear=wear,
        )
        if ev:
            self.place_event(run, ev[0], int(ev[0].fraction * n_total))
        return run

    def place_event(self, run: BlockRun, ev: ProcessEvent, at: int) -> EventTruth:
        """Inject ``ev`` into the block under way from its sample ``at`` on (``ev.part``,
        ``ev.line`` and ``ev.fraction`` are not read); returns its truth.

        Raises
        ------
        ParameterError
            ``at`` already run or past the block's end, or the block has an event already.
        """
        if run.event:
            raise ParameterError("events", "at most one event per part and block", 2)
        if int(at) != at or not run.done <= at < run.n_total:
            raise ParameterError(
                "at", f"a sample of the block not yet run, in [{run.done}, {run.n_total})", at
            )
        at = int(at)
        run.k_ev = at
        run.event = ev.kind
        if ev.kind == ProcessEventKind.BREAKAGE:
            run.dr1[ev.flute % run.tool.n_flutes] -= ev.size
        elif ev.kind == ProcessEventKind.COLLISION:
            run.feed_mul = ev.size
            if run.blk.cut:
                # the tool driven on at the wrong feed stays in the part (no exit)
                run.stock[1] = math.inf
        else:
            run.depth_after = 1.0 - ev.size
        k = run.k_start + at
        tr = EventTruth(
            ev.kind, k * self.sample_time, k, ev.size, run.tool.number, run.blk.line, run.part
        )
        run.truth.append(tr)
        return tr

    def advance(self, run: BlockRun, n: int) -> BlockRecord:
        """The next ``min(n, run.left)`` samples (>= 1) of the block under way."""
        n = min(int(n), run.left)
        if n < 1:
            raise ParameterError("n", f"a sample count in [1, {run.left}]", n)
        ts = self.sample_time
        inst = self.instances[run.tool.number]
        blk, tool = run.blk, run.tool
        out = np.empty((len(_ROWS), n))
        cut = ProcessCut(
            ts=ts,
            nf=tool.n_flutes,
            lags=run.lags,
            dz=run.dz,
            phi_st=run.phi_st,
            phi_ex=run.phi_ex,
            kc=run.kc,
            ecc=inst.ecc,
            ecc_phase=math.radians(inst.ecc_deg),
            omega=run.omega,
            v_target=run.v_target,
            acc=2.0,
            stock=run.stock,
            a_m=self.modulation[0],
            theta_m=self.modulation[1],
        )
        change = ProcessChange(run.k_ev - run.done, run.dr0, run.dr1, run.feed_mul, run.depth_after)
        _process_kernel(n, cut, change, self._drive, self.st, self.ax, self.hist, out)
        kf = (self.drives.x.force_constant, self.drives.y.force_constant)
        rec = BlockRecord(
            k0=self.k,
            t=np.asarray((self.k + np.arange(n)) * ts, dtype=np.float64),
            x=out[2],
            y=out[3],
            ix=out[4] / kf[0],
            iy=out[5] / kf[1],
            psi=out[6],
            tool=tool.number,
            program=self.program.name,
            line=blk.line,
            part=run.part,
            override=run.override if blk.cut else 1.0,
            spindle_rpm=blk.spindle_rpm,
            cut=blk.cut,
            fx=out[0],
            fy=out[1],
            engaged=out[7],
            wear=run.wear,
            events=[tr for tr in run.truth if self.k <= tr.sample < self.k + n],
        )
        self.k += n
        run.done += n
        return rec

    def end_block(self, run: BlockRun) -> None:
        """Close a block (run to its end or cut short): a breakage persists (a broken or
        chipped flute stays so), the tool wears by the time it cut, and a tool at its wear
        limit is replaced by a fresh instance."""
        inst = self.instances[run.tool.number]
        tool = run.tool
        if run.event == ProcessEventKind.BREAKAGE and run.done > run.k_ev:
            inst.dr[: tool.n_flutes] = run.dr1
        if run.blk.cut:
            inst.wear += tool.wear_per_s * run.done * self.sample_time
            if inst.wear >= tool.wear_limit:
                self.instances[tool.number] = self._new_instance(tool)
                self.tool_changes += 1


def default_program(name: str = "O1001", *, rpm_scale: float = 1.0) -> PartProgram:
    """The default part: a face and a slot with tool 1, a contour with tool 2.

    Three operations with air moves between them, a tool change (T1 -> T2) and spindle
    steps; about 12 s per part at 100 % override.
    """
    t1 = Tool(number=1, n_flutes=4, diameter=10e-3, eccentricity=8e-6, eccentricity_deg=40.0)
    t2 = Tool(
        number=2, n_flutes=3, diameter=8e-3, eccentricity=6e-6, eccentricity_deg=200.0,
        helix_deg=35.0,
    )  # fmt: skip
    r = rpm_scale
    blocks = (
        ProgramBlock(10, 1, False, 0.010, spindle_rpm=1200 * r, air_speed=0.02),
        ProgramBlock(20, 1, True, 0.020, spindle_rpm=1200 * r, feed_per_tooth=60e-6,
                     axial_depth=1.0e-3, radial_immersion=0.5),
        ProgramBlock(30, 1, False, 0.008, spindle_rpm=1500 * r, air_speed=0.02),
        ProgramBlock(40, 1, True, 0.015, spindle_rpm=1500 * r, feed_per_tooth=50e-6,
                     axial_depth=1.5e-3, radial_immersion=1.0),
        ProgramBlock(50, 2, False, 0.010, spindle_rpm=1800 * r, air_speed=0.02),
        ProgramBlock(60, 2, True, 0.018, spindle_rpm=1800 * r, feed_per_tooth=40e-6,
                     axial_depth=2.0e-3, radial_immersion=0.2, down_milling=True),
        ProgramBlock(70, 2, False, 0.010, spindle_rpm=1800 * r, air_speed=0.02),
    )  # fmt: skip
    return PartProgram(name, blocks, (t1, t2))


def with_tool(program: PartProgram, tool: Tool) -> PartProgram:
    """The program with one tool replaced (same number)."""
    tools = tuple(tool if t.number == tool.number else t for t in program.tools)
    return replace(program, tools=tools)


__all__ = [
    "EVENT_KINDS",
    "BlockRecord",
    "BlockRun",
    "EventTruth",
    "PartProgram",
    "ProcessEvent",
    "ProcessMachine",
    "ProgramBlock",
    "Tool",
    "default_program",
    "with_tool",
]
