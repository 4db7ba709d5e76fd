r"""The machining centre as a simulation: ``step(state, n) -> (state, record)``.

:class:`MachiningCentre` holds what does not change (the machine's parameters, the part
program, the shop's variation, the events to inject); :class:`CentreState` everything
that does (the drives' and spindle's states, the program's cursor, the magazine's tools,
the workpiece, the random generators of the shop's draws and of the noise).
:meth:`MachiningCentre.step` advances ``n`` samples at the simulation rate (10 kHz)
through the numba kernel of :mod:`machine.centre.kernel`, block of the part program by
block, and returns a new state and a :class:`CentreRecord`: what the drives measure, the
CNC's identities (tool, program, line, part, override), and the truth beside them
(process forces, cutting torque, engagement, flank wear, the events injected).

The shop's variation (a choice, as in :mod:`machine.process`): one part in five runs at
a feed override of 80-120 %, each blank's depth of cut varies by 2 % (1 sigma), a worn
tool (VB >= 0.3 mm) is replaced at the end of its block by a new instance with its own
runout and life. Events (:class:`machine.process.ProcessEvent`: breakage, collision,
missing tool) are placed in a part's block where the program says, or injected into the
running cut (:meth:`MachiningCentre.inject`); a breakage and a missing (broken-off) tool
stay with the tool instance until it is replaced (:meth:`MachiningCentre.replace_tool`).

Examples
--------
>>> m = MachiningCentre()
>>> state = m.initial_state(seed=0)
>>> state, rec = m.step(state, 5000)   # 0.5 s
>>> rec.signal("S.speed").shape
(5000,)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from common.arrays import F64
from common.linalg import zoh
from machine.centre import kernel as kn
from machine.centre.params import GRAVITY, CentreParams, FeedAxisParams
from machine.centre.program import Block, Program, blank_mass, default_program
from machine.centre.tools import MAX_FLUTES, VB_LIMIT, MagazineTool, ToolState, new_instance
from machine.errors import ParameterError, require_in, require_nonnegative
from machine.process import EVENT_KINDS, EventTruth, ProcessEvent

#: Coulomb friction's smoothing speed: feed axes [m/s], spindle [rad/s]
_VS_AXIS, _WS_SPINDLE = 1e-4, 0.5
#: the kernel's kind of each program block kind
_KERNEL_KIND = {"rapid": kn.K_MOVE, "feed": kn.K_MOVE, "tool_change": kn.K_DWELL,
                "dwell": kn.K_DWELL, "end": kn.K_DWELL, "spindle": kn.K_SPINDLE}  # fmt: skip
#: rows of the noise drawn per step: the three axes' currents and the spindle's
_NOISE_ROWS = 4


@dataclass
class BlockRun:
    """The program block under way: the kernel's packed arrays for it, and its event."""

    index: int
    k_start: int
    pp: F64
    cp: F64
    lags: F64
    dr0: F64
    dr1: F64
    nominal: int
    event: str = ""
    truth: list[EventTruth] = field(default_factory=list)
    cut_samples: int = 0

    def copy(self) -> BlockRun:
        return BlockRun(
            self.index, self.k_start, self.pp.copy(), self.cp.copy(), self.lags.copy(),
            self.dr0.copy(), self.dr1.copy(), self.nominal, self.event, list(self.truth),
            self.cut_samples,
        )  # fmt: skip


@dataclass
class CentreState:
    """Everything of the machine that changes (see the module docstring).

    ``k`` samples run; ``part`` the part being machined (0-based); ``cursor`` the index
    of the running block; ``ax`` (3 x kernel.N_AX), ``ss``, ``ps``, ``hist`` the kernel's
    states; ``phi``, ``gam`` the axes' discretised mechanics (they follow the workpiece's
    mass); ``tools`` the magazine; ``spindle_tool`` the tool in the spindle (0: none);
    ``workpiece`` the blank's mass [kg]; ``part_override`` the shop's feed override of
    this part, ``feed_override``/``spindle_override`` the operator's; ``depth_scale`` this
    blank's depth factor; ``pending`` events waiting for a cut block; ``run`` the block
    under way.
    """

    k: int
    part: int
    cursor: int
    ax: F64
    ss: F64
    ps: F64
    hist: F64
    head: int
    phi: F64
    gam: F64
    tools: dict[int, ToolState]
    spindle_tool: int
    workpiece: float
    rng: np.random.Generator
    noise_rng: np.random.Generator
    part_override: float = 1.0
    feed_override: float = 1.0
    spindle_override: float = 1.0
    depth_scale: float = 1.0
    tool_changes: int = 0
    pending: list[ProcessEvent] = field(default_factory=list)
    run: BlockRun | None = None
    mass_changed: bool = False
    structure: F64 = field(default_factory=lambda: np.zeros(0))

    def copy(self) -> CentreState:
        """A deep copy (the random generator included)."""
        rng, noise = _copy_rng(self.rng), _copy_rng(self.noise_rng)
        return CentreState(
            self.k, self.part, self.cursor, self.ax.copy(), self.ss.copy(), self.ps.copy(),
            self.hist.copy(), self.head, self.phi.copy(), self.gam.copy(),
            {n: t.copy() for n, t in self.tools.items()}, self.spindle_tool, self.workpiece,
            rng, noise, self.part_override, self.feed_override, self.spindle_override,
            self.depth_scale, self.tool_changes, list(self.pending),
            None if self.run is None else self.run.copy(), self.mass_changed,
            self.structure.copy(),
        )  # fmt: skip


def _copy_rng(rng: np.random.Generator) -> np.random.Generator:
    out = np.random.Generator(type(rng.bit_generator)())
    out.bit_generator.state = rng.bit_generator.state
    return out


@dataclass
class CentreRecord:
    """One step's samples at the simulation rate.

    ``rows`` (:data:`machine.centre.kernel.ROWS` x n): per axis ``q_cmd, q_m, q_l, qd_m,
    i_m`` measured and ``f_process`` (the force on the workpiece along the axis [N]),
    ``x_load`` truth; spindle ``speed, current, power, speed_cmd`` measured and
    ``torque_cut, speed_true, psi`` truth; ``engaged`` truth. Identities per sample:
    ``tool`` (0: none in the spindle), ``line``, ``part``, ``override`` (feed override,
    1 = 100 %). Truth per sample: ``vb`` the flank wear of the tool in the spindle [m].
    ``events``: the injected events whose first sample is in this record.
    """

    k0: int
    t: F64
    rows: F64
    tool: np.ndarray
    line: np.ndarray
    part: np.ndarray
    override: F64
    vb: F64
    program: str
    events: list[EventTruth]

    @property
    def n(self) -> int:
        return int(self.t.shape[0])

    def signal(self, name: str) -> F64:
        """One row by name (``X.i_m``, ``S.power``, ``engaged``...)."""
        try:
            return self.rows[kn.ROWS.index(name)]
        except ValueError:
            raise ParameterError("name", f"one of {list(kn.ROWS)}", name) from None


def _axis_matrices(ax: FeedAxisParams, workpiece: float, ts: float) -> tuple[F64, F64]:
    """Exact ZOH matrices of one axis' mechanics (4 states; a rigid axis as two copies)."""
    mm, ml = ax.motor_mass, ax.load(workpiece)
    bm, bl = ax.motor_viscous / ax.p**2, ax.load_viscous
    if ax.kind == "two_inertia":
        k, c = ax.stiffness, ax.spring_damping(workpiece)
        a = np.array([[0.0, 1.0, 0.0, 0.0],
                      [-k / mm, -(bm + c) / mm, k / mm, c / mm],
                      [0.0, 0.0, 0.0, 1.0],
                      [k / ml, c / ml, -k / ml, -(bl + c) / ml]])  # fmt: skip
        b = np.array([[0.0, 0.0], [1.0 / mm, 0.0], [0.0, 0.0], [0.0, 1.0 / ml]])
        return zoh(a, b, ts)
    mt = mm + ml
    p2, g2 = zoh(np.array([[0.0, 1.0], [0.0, -(bm + bl) / mt]]), np.array([[0.0], [1.0 / mt]]), ts)
    phi = np.zeros((4, 4))
    phi[:2, :2] = p2
    phi[2:, 2:] = p2
    gam = np.zeros((4, 2))
    gam[:2, 0] = gam[:2, 1] = gam[2:, 0] = gam[2:, 1] = g2[:, 0]
    return phi, gam


def _pack_axis(ax: FeedAxisParams, blank: float, ts: float) -> F64:
    """The kernel's parameters of one axis (kernel.AP_*); gains from the blank's mass."""
    p = np.zeros(kn.N_AP)
    kp, ki = ax.speed_gains(blank)
    p[kn.AP_KV], p[kn.AP_KP], p[kn.AP_KI] = ax.kv, kp, ki
    p[kn.AP_MFF] = ax.total_mass(blank)
    p[kn.AP_BI] = 1.0 - math.exp(-2.0 * math.pi * ax.current_hz * ts)
    p[kn.AP_BF] = 1.0 - math.exp(-ts / ax.speed_filter)
    p[kn.AP_FMAX], p[kn.AP_KF] = ax.peak_force, ax.force_constant
    p[kn.AP_QM], p[kn.AP_QL] = ax.encoder_quantum, ax.scale_resolution
    p[kn.AP_FCM], p[kn.AP_FCL] = ax.motor_coulomb / ax.p, ax.load_coulomb
    p[kn.AP_GRAV] = ax.load_mass * GRAVITY if ax.gravity else 0.0
    p[kn.AP_NOISE], p[kn.AP_LSB], p[kn.AP_VS] = ax.current_noise, ax.current_lsb, _VS_AXIS
    p[kn.AP_SCALE] = 1.0 if ax.kind == "two_inertia" else 0.0
    return p


def _pack_spindle(params: CentreParams) -> F64:
    sp, ts = params.spindle, params.sample_time
    p = np.zeros(kn.N_SP)
    p[kn.SP_KP], p[kn.SP_KI] = sp.speed_gains()
    p[kn.SP_BI] = 1.0 - math.exp(-2.0 * math.pi * sp.current_hz * ts)
    p[kn.SP_BF] = 1.0 - math.exp(-ts / sp.speed_filter)
    e1 = math.exp(-sp.viscous / sp.inertia * ts)
    p[kn.SP_E1] = e1
    p[kn.SP_E2] = (1.0 - e1) / sp.viscous if sp.viscous > 0 else ts / sp.inertia
    p[kn.SP_TMAX], p[kn.SP_PMAX] = sp.rated_torque, sp.max_power
    p[kn.SP_TC], p[kn.SP_WSHARE], p[kn.SP_WTIME] = sp.coulomb, sp.warmup_share, sp.warmup_time
    p[kn.SP_RAMP], p[kn.SP_KT], p[kn.SP_NOISE] = sp.ramp, sp.torque_constant, sp.current_noise
    p[kn.SP_BP] = 1.0 - math.exp(-ts / sp.power_smoothing)
    p[kn.SP_WS] = _WS_SPINDLE
    return p


def trapezoid_time(length: float, speed: float, acc: float) -> float:
    """Duration of a rest-to-rest move [s] at ``speed`` with the acceleration limit."""
    if speed <= 0.0:
        return math.inf
    if length >= speed * speed / acc:
        return length / speed + speed / acc
    return 2.0 * math.sqrt(length / acc)


class MachiningCentre:
    """The 3-axis machining centre running a part program (see the module docstring).

    Parameters
    ----------
    params : CentreParams
        The machine (default: the one :mod:`machine.centre.params` describes).
    program : Program
        The part program run part after part (default :func:`default_program`).
    events : list of ProcessEvent
        Events to inject (part, line, where in the block, size).
    override_prob : float
        Chance per part of a feed override other than 100 % (one of 80, 90, 110, 120 %).
    depth_spread : float
        Relative spread (1 sigma) of the depth of cut from one blank to the next.
    n_layers : int
        Axial layers of seed003 (1).
    """

    def __init__(
        self,
        params: CentreParams | None = None,
        program: Program | None = None,
        *,
        events: list[ProcessEvent] | None = None,
        override_prob: float = 0.2,
        depth_spread: float = 0.02,
        n_layers: int = 5,
    ) -> None:
        self.params = params if params is not None else CentreParams()
        self.program = program if program is not None else default_program()
        self.events = list(events or [])
        self.override_prob = require_in("override_prob", override_prob, 0.0, 1.0)
        self.depth_spread = require_nonnegative("depth_spread", depth_spread)
        if int(n_layers) != n_layers or not 1 <= n_layers <= 50:
            raise ParameterError("n_layers", "an integer in [1, 50]", n_layers)
        self.n_layers = int(n_layers)
        self._check_program()
        ts = self.sample_time
        self.blank = blank_mass(self.params.workpiece_density)
        self._axp = np.stack([_pack_axis(a, self.blank, ts) for a in self.params.axes])
        self._spp = _pack_spindle(self.params)
        self._plan = self.program.walk()
        self._hlen = self._history_length()
        #: the tool/workpiece structure's packed parameters (issue 29 plugs its modes in
        #: here and in CentreState.structure; empty: rigid)
        self._struct = np.zeros(0)

    @property
    def sample_time(self) -> float:
        return self.params.sample_time

    def _check_program(self) -> None:
        for b in self.program.blocks:
            if b.target is None:
                continue
            for ax, v in zip(self.params.axes, b.target, strict=True):
                lo, hi = ax.travel
                if not lo <= v <= hi:
                    raise ParameterError(
                        f"line N{b.line}.target.{ax.name}",
                        f"inside the travel [{lo:g}, {hi:g}] m",
                        v,
                    )
        for t in self.program.tools:
            if t.n_flutes > MAX_FLUTES:
                raise ParameterError(f"T{t.number}.n_flutes", f"<= {MAX_FLUTES}", t.n_flutes)
        for b, tool_no, _, _ in self.program.walk():
            if b.cut is not None:
                t = self.program.tool(tool_no)
                lag = 2.0 * b.cut.axial_depth * math.tan(math.radians(t.helix_deg)) / t.diameter
                if lag >= 2.0 * math.pi:
                    raise ParameterError(f"line N{b.line}.cut.axial_depth",
                                         "a depth whose helix lag is under one turn",
                                         b.cut.axial_depth)  # fmt: skip
            top = self.params.spindle.max_rpm
            if b.kind == "spindle" and b.rpm > top:
                raise ParameterError(f"line N{b.line}.rpm", f"<= the spindle's {top:g} rpm", b.rpm)

    def _history_length(self) -> int:
        periods = [
            60.0 / (rpm * self.program.tool(tool).n_flutes)
            for b, tool, rpm, _ in self._plan
            if b.cut is not None
        ]
        return math.ceil(2.0 * max(periods, default=0.01) / self.sample_time) + 16

    # ------------------------------------------------------------------ state
    def initial_state(self, seed: int | None = 0) -> CentreState:
        """The machine at rest at the program's start point, spindle stopped and cold,
        fresh tools, part 0 about to start. ``seed`` seeds two generators: the shop's
        draws and the measurement noise (apart, so a run's draws do not depend on how it
        is cut into steps)."""
        shop, noise = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2))
        ax = np.zeros((3, kn.N_AX))
        for i, a in enumerate(self.params.axes):
            x0 = self.program.start[i]
            ax[i, kn.AX_XM] = ax[i, kn.AX_XL] = x0
            ax[i, kn.AX_QPREV] = math.floor(x0 / a.encoder_quantum) * a.encoder_quantum
            # the speed loop's integral holds the weight (Z) from the start
            ax[i, kn.AX_INT] = ax[i, kn.AX_FA] = self._axp[i, kn.AP_GRAV]
        phi, gam = self._matrices(self.blank)
        tools = {t.number: new_instance(t, None) for t in self.program.tools}
        ps = np.zeros(kn.N_PS)
        ps[kn.PS_OVR] = ps[kn.PS_SOVR] = 1.0
        return CentreState(
            k=0, part=0, cursor=0, ax=ax, ss=np.zeros(kn.N_SS), ps=ps,
            hist=np.zeros((self._hlen, 2)), head=0, phi=phi, gam=gam, tools=tools,
            spindle_tool=0, workpiece=self.blank, rng=shop, noise_rng=noise,
        )  # fmt: skip

    def _matrices(self, workpiece: float) -> tuple[F64, F64]:
        mats = [_axis_matrices(a, workpiece, self.sample_time) for a in self.params.axes]
        return np.stack([m[0] for m in mats]), np.stack([m[1] for m in mats])

    # ------------------------------------------------------------------ stepping
    def step(self, state: CentreState, n: int) -> tuple[CentreState, CentreRecord]:
        """Advance ``n`` samples (>= 1) from ``state`` (left as it was)."""
        if int(n) != n or n < 1:
            raise ParameterError("n", "a sample count >= 1", n)
        st = state.copy()
        n = int(n)
        out = np.empty((kn.N_ROWS, n))
        ids = np.zeros((3, n), dtype=np.int64)
        ovr = np.empty(n)
        vb = np.empty(n)
        # drawn sample by sample (rows of 4), so any chunking of a run draws the same
        noise = np.ascontiguousarray(st.noise_rng.standard_normal((n, _NOISE_ROWS)).T)
        events: list[EventTruth] = []
        k0, k = st.k, 0
        while k < n:
            if st.run is None:
                self._begin_block(st)
            run = st.run
            assert run is not None
            run.cp[kn.CP_HEAD] = st.head
            used = kn.step_block(
                n - k,
                k,
                kn.CentreDesign(self.sample_time, self._axp, st.phi, st.gam, self._spp,
                                self._struct),
                kn.CentreBlock(run.pp, run.cp, run.lags, run.dr0, run.dr1),
                kn.CentreArrays(st.ax, st.ss, st.ps, st.hist, st.structure),
                noise,
                out,
            )  # fmt: skip
            st.head = int(run.cp[kn.CP_HEAD])
            blk = self.program.blocks[run.index]
            ids[:, k : k + used] = np.array([[st.spindle_tool], [blk.line], [st.part]])
            ovr[k : k + used] = st.ps[kn.PS_OVR]
            tool = st.tools.get(st.spindle_tool)
            vb[k : k + used] = tool.vb() if tool is not None else 0.0
            run.cut_samples += int(np.count_nonzero(out[kn.R_ENGAGED, k : k + used] > 0.0))
            events += [e for e in run.truth if st.k <= e.sample < st.k + used]
            st.k += used
            k += used
            if st.ps[kn.PS_DONE] != 0.0:
                self._end_block(st)
        t = np.asarray((k0 + np.arange(n)) * self.sample_time, dtype=np.float64)
        rec = CentreRecord(k0, t, out, ids[0], ids[1], ids[2], ovr, vb, self.program.name, events)
        return st, rec

    def _begin_block(self, st: CentreState) -> None:
        if st.cursor == 0:
            self._begin_part(st)
        blk, tool_no, rpm, start = self._plan[st.cursor]
        pp = np.zeros(kn.N_PP)
        pp[kn.PP_KIND] = _KERNEL_KIND[blk.kind]
        pp[kn.PP_SECONDS] = blk.seconds
        pp[kn.PP_ACC] = self.params.acceleration
        pp[kn.PP_RPM] = blk.rpm if blk.kind == "spindle" else (
            0.0 if blk.kind in ("tool_change", "end") else rpm)  # fmt: skip
        nominal = max(1, round(blk.seconds / self.sample_time))
        pp[kn.PP_P0 : kn.PP_P0 + 3] = start
        if blk.target is not None:
            d = np.subtract(blk.target, start)
            length = float(np.linalg.norm(d))
            pp[kn.PP_U : kn.PP_U + 3] = d / length if length > 0 else 0.0
            pp[kn.PP_L] = length
            pp[kn.PP_V] = self.params.rapid if blk.kind == "rapid" else blk.feed
            dur = trapezoid_time(length, pp[kn.PP_V] * st.ps[kn.PS_OVR], pp[kn.PP_ACC])
            nominal = max(1, round(dur / self.sample_time)) if math.isfinite(dur) else 1
        run = self._cut_run(st, blk, tool_no, pp, nominal)
        st.run = run
        st.ps[[kn.PS_S, kn.PS_V, kn.PS_T, kn.PS_K, kn.PS_DONE]] = 0.0
        if st.mass_changed:
            st.phi, st.gam = self._matrices(st.workpiece)
            st.mass_changed = False
        self._place_scheduled(st, run, blk)

    def _cut_run(
        self, st: CentreState, blk: Block, tool_no: int, pp: F64, nominal: int
    ) -> BlockRun:
        cp = np.zeros(kn.N_CP)
        cp[kn.CP_K_EV] = np.inf
        cp[kn.CP_FEED_MUL] = 1.0
        cp[kn.CP_NF] = 1.0
        dr = np.zeros(MAX_FLUTES)
        lags = np.zeros(1)
        if blk.cut is not None and tool_no in st.tools:
            tool = self.program.tool(tool_no)
            ts_ = st.tools[tool_no]
            cut = blk.cut
            d = pp[kn.PP_U : kn.PP_U + 2]
            cp[kn.CP_ACTIVE] = 1.0
            cp[kn.CP_PHI_ST], cp[kn.CP_PHI_EX] = cut.window()
            cp[kn.CP_BETA] = math.atan2(d[1], d[0])
            cp[kn.CP_RAMP], cp[kn.CP_RADIUS] = tool.radius, tool.radius
            cp[kn.CP_RAMP_IN], cp[kn.CP_RAMP_OUT] = float(cut.ramp_in), float(cut.ramp_out)
            cp[kn.CP_NF] = tool.n_flutes
            cp[kn.CP_KTC : kn.CP_KAE + 1] = tool.coefficients(ts_.vb())
            cp[kn.CP_ECC], cp[kn.CP_ECC_PH] = ts_.ecc, math.radians(ts_.ecc_deg)
            cp[kn.CP_LOST] = ts_.lost
            # a straight-fluted tool (no helix) has one layer: every layer would be alike
            layers = self.n_layers if tool.helix_deg > 0.0 else 1
            cp[kn.CP_DZ] = cut.axial_depth * st.depth_scale / layers
            z = (np.arange(layers) + 0.5) * cut.axial_depth / layers
            lags = 2.0 * z * math.tan(math.radians(tool.helix_deg)) / tool.diameter

            dr = ts_.dr.copy()
        return BlockRun(st.cursor, st.k, pp, cp, lags, dr, dr.copy(), nominal)

    def _begin_part(self, st: CentreState) -> None:
        """The shop's draws for the next part (override, the blank's depth) and its blank."""
        st.part_override = 1.0
        if st.rng.random() < self.override_prob:
            st.part_override = float(st.rng.choice([0.8, 0.9, 1.1, 1.2]))
        st.depth_scale = 1.0 + self.depth_spread * float(st.rng.standard_normal())
        st.ps[kn.PS_OVR] = st.part_override * st.feed_override
        if st.workpiece != self.blank:
            st.workpiece = self.blank
            st.mass_changed = True

    def _end_block(self, st: CentreState) -> None:
        run = st.run
        assert run is not None
        blk, tool_no, _, _ = self._plan[run.index]
        if blk.cut is not None and tool_no in st.tools:
            self._wear(st, run, blk, tool_no)
        if blk.kind == "tool_change":
            st.spindle_tool = blk.tool
        st.run = None
        st.cursor += 1
        if st.cursor >= len(self.program.blocks):
            st.cursor = 0
            st.part += 1

    def _wear(self, st: CentreState, run: BlockRun, blk: Block, tool_no: int) -> None:
        """After a cut block: the event's lasting damage, the wear, the metal removed."""
        tool = self.program.tool(tool_no)
        inst = st.tools[tool_no]
        ran = st.ps[kn.PS_K]
        if run.event == "breakage" and ran > run.cp[kn.CP_K_EV]:
            inst.dr[:] = run.dr1
        if run.event == "missing_tool" and ran > run.cp[kn.CP_K_EV]:
            inst.lost = 1.0 - (1.0 - inst.lost) * (1.0 - run.cp[kn.CP_LOST_AFTER])
        seconds = run.cut_samples * self.sample_time
        rpm = run.pp[kn.PP_RPM] * st.ps[kn.PS_SOVR]
        inst.cut_time += seconds
        inst.t_eq += seconds * tool.speed_factor(rpm)
        assert blk.cut is not None
        width = blk.cut.radial_immersion * tool.diameter
        depth = blk.cut.axial_depth * st.depth_scale * (1.0 - inst.lost)
        ramps = 0.5 * tool.radius * (blk.cut.ramp_in + blk.cut.ramp_out)
        removed = max(run.pp[kn.PP_L] - ramps, 0.0) * width * depth
        st.workpiece = max(st.workpiece - self.params.workpiece_density * removed, 0.0)
        st.mass_changed = True
        if inst.vb() >= VB_LIMIT:
            self._replace(st, tool)

    def _replace(self, st: CentreState, tool: MagazineTool) -> None:
        old = st.tools[tool.number]
        st.tools[tool.number] = new_instance(tool, st.rng, old.instance + 1)
        st.tool_changes += 1

    # ------------------------------------------------------------------ events
    def _place_scheduled(self, st: CentreState, run: BlockRun, blk: Block) -> None:
        evs = [e for e in self.events if e.part == st.part and e.line == blk.line]
        if len(evs) > 1:
            raise ParameterError("events", "at most one event per part and block", len(evs))
        if not evs and blk.cut is not None:
            # a pending event: the first due in this part for this line (line 0: any cut)
            due = [e for e in st.pending if e.part <= st.part and e.line in (0, blk.line)]
            if due:
                st.pending.remove(due[0])
                evs = due[:1]
        if evs:
            ev = evs[0]
            self._place(st, run, ev.kind, ev.size, ev.flute, int(ev.fraction * run.nominal))

    def _place(self, st: CentreState, run: BlockRun, kind: str, size: float, flute: int,
               at: int) -> EventTruth:  # fmt: skip
        if run.event:
            raise ParameterError("events", "at most one event per part and block", 2)
        blk, tool_no, _, _ = self._plan[run.index]
        run.cp[kn.CP_K_EV] = at
        run.event = kind
        if kind == "breakage":
            nf = int(run.cp[kn.CP_NF])
            run.dr1[flute % nf] -= size
        elif kind == "collision":
            run.cp[kn.CP_FEED_MUL] = size
        else:
            run.cp[kn.CP_LOST_AFTER] = size
        k = run.k_start + at
        tr = EventTruth(kind, k * self.sample_time, k, size, tool_no, blk.line, st.part)
        run.truth.append(tr)
        return tr

    def inject(
        self, state: CentreState, kind: str, size: float, *, flute: int = 0
    ) -> tuple[CentreState, bool]:
        """An event now: into the running block from its next sample if it cuts, else
        into the middle of the next cut block. Returns the new state and whether it was
        placed now (False: it waits for a cut).

        ``size`` as :class:`machine.process.ProcessEvent` (radius lost [m], feed
        multiplier, share of the engagement lost).
        """
        ev = ProcessEvent(kind, max(state.part, 0), 0, 0.5, size, flute)
        st = state.copy()
        run = st.run
        if run is not None and run.cp[kn.CP_ACTIVE] != 0.0 and not run.event:
            self._place(st, run, ev.kind, ev.size, ev.flute, int(st.ps[kn.PS_K]))
            return st, True
        st.pending.append(ev)
        return st, False

    def schedule(self, state: CentreState, event: ProcessEvent) -> CentreState:
        """Place ``event`` later in this run: in its part (or, if that part is over, the
        next one) at its line and where in the block it says (line 0: the next cut).

        Raises
        ------
        ParameterError
            ``event.line`` is neither 0 nor a cut block of the program.
        """
        cuts = [b.line for b in self.program.blocks if b.cut is not None]
        if event.line not in (0, *cuts):
            raise ParameterError("event.line", f"0 (the next cut) or a cut line of {cuts}",
                                 event.line)  # fmt: skip
        st = state.copy()
        st.pending.append(event)
        return st

    def replace_tool(self, state: CentreState, number: int) -> CentreState:
        """The operator mounts a fresh instance of tool ``number`` (after a breakage)."""
        st = state.copy()
        self._replace(st, self.program.tool(number))
        return st

    def set_modulation(self, state: CentreState, a_m: float, theta_m: float) -> CentreState:
        """seed003 (7)'s circle on the X and Y commands from the next sample: radius
        ``a_m`` [m] (at most 100 um; negative: the circle at ``theta_m + pi``), phase
        ``theta_m`` [rad] to the spindle angle; held until changed (0: none)."""
        if not (math.isfinite(a_m) and math.isfinite(theta_m)) or abs(a_m) > 100e-6:
            raise ParameterError("a_m", "a finite radius <= 100e-6 m", a_m)
        st = state.copy()
        st.ps[kn.PS_AM], st.ps[kn.PS_THM] = float(a_m), float(theta_m)
        return st

    def cancelling_modulation(self, state: CentreState) -> tuple[float, float]:
        """Truth: the ``(a_m, theta_m)`` whose carriage motion cancels the runout of the tool
        in the spindle at the commanded speed, through the mean of the X and Y command
        responses (:func:`machine.centre.loops.tracking_response`)."""
        from machine.centre.loops import tracking_response

        tool = state.tools.get(state.spindle_tool)
        rpm = float(self._plan[state.cursor][2] if state.run is None else state.run.pp[kn.PP_RPM])
        if tool is None or rpm <= 0.0:
            raise ParameterError(
                "state", "a tool in the turning spindle", (state.spindle_tool, rpm)
            )
        f = abs(rpm) * state.spindle_override / 60.0
        g = 0.5 * sum(tracking_response(a, f, self.params, workpiece=state.workpiece)
                      for a in ("X", "Y"))  # fmt: skip
        u = -tool.ecc * complex(math.cos(math.radians(tool.ecc_deg)),
                                math.sin(math.radians(tool.ecc_deg))) / g  # fmt: skip
        return abs(u), math.atan2(u.imag, u.real) % (2.0 * math.pi)

    def set_overrides(
        self, state: CentreState, *, feed: float | None = None, spindle: float | None = None
    ) -> CentreState:
        """The operator's feed override (0: a feed hold; up to 1.2) and spindle override
        (0.5-1.2), from the next sample."""
        st = state.copy()
        if feed is not None:
            st.feed_override = require_in("feed_override", feed, 0.0, 1.2)
            st.ps[kn.PS_OVR] = st.part_override * st.feed_override
        if spindle is not None:
            st.spindle_override = require_in("spindle_override", spindle, 0.5, 1.2)
            st.ps[kn.PS_SOVR] = st.spindle_override
        return st


__all__ = [
    "EVENT_KINDS",
    "BlockRun",
    "CentreRecord",
    "CentreState",
    "MachiningCentre",
    "trapezoid_time",
]
