r"""The process monitor on the machining centre, at a CNC's trace rates (issue 32 items 1-2).

Each seed's machining centre (:mod:`machine.centre`) is simulated **once**, at 10 kHz;
every chunk of it is exported as the CNC's trace at 5 kHz, 1 kHz and 500 Hz (point
samples, :class:`machine.centre.trace.CncTrace`), and each trace is watched on three
signal sets by the same :class:`estimators.monitoring.process.ProcessMonitor`:

``spindle``
    the spindle drive alone: the cutting torque from its current and measured speed,
    :math:`T_{cut} = (K_t i\,\omega - \hat P_0(\omega)) / \omega` with the idle power
    :math:`\hat P_0` taught per speed in the air (:class:`estimators.monitoring.spindle_power.
    IdlePower`), as the tangential force at the tool's radius, :math:`T_{cut} / R` (the
    CNC's tool table knows the radius);
``axes``
    the X and Y feed drives alone: each axis' process force from its motor current and
    encoder, seed 000's disturbance observer with the axis taken as one mass
    (:class:`estimators.force_observer.TorsionEstimator`, the nominal mass, viscous and
    Coulomb friction, Q(s) designed from the rate: :func:`~estimators.force_observer.
    q_cutoff`);
``both``
    both monitors, an alarm from either (the machine watched on everything it gives).

The spindle angle every monitor reads is the CNC's: the integral of the measured spindle
speed (no truth reaches a detector). So every comparison, rate against rate and signal
set against signal set, is paired: the same cut, the same event, the same noise.
"""

from __future__ import annotations

import hashlib
import math
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from common.event_kinds import ProcessEventKind
from server.pipeline.block_motion import cutting_lines

#: the trace rates compared [Hz]
RATES = (5000.0, 1000.0, 500.0)
#: the signal sets
SETS = ("spindle", "axes", "both")
#: the monitors behind the signal sets
MONITORS = ("spindle", "axes")
TEACH_PARTS = 5
#: simulated samples per chunk (1 s; a multiple of every trace factor)
CHUNK = 10_000
#: spindle speeds drawn log-uniform over this range [rpm]: 20 to 2.5 samples per
#: revolution at 500 Hz
RPM_RANGE = (1500.0, 12000.0)
#: the event sizes of the clear class (as the issue-21 reproduction's)
SIZES: dict[str, tuple[float, float]] = {
    ProcessEventKind.BREAKAGE: (0.2e-3, 0.6e-3),
    ProcessEventKind.COLLISION: (4.0, 8.0),
    ProcessEventKind.MISSING_TOOL: (1.0, 1.0),
}
#: the speed below which a velocity counts as standing [m/s] (the observer's friction
#: sign, smoothed: the trace's quantised velocity at rest must not switch it)
_V_SMOOTH = 1e-4


@dataclass(frozen=True)
class CentreCase:
    """One seed on the machining centre: an event (kind) or event-free ``hours``."""

    kind: str
    seed: int
    hours: float = 0.0
    machine: str = "centre"
    size: str = "clear"


def _code(s: str) -> int:
    return int(hashlib.sha256(s.encode()).hexdigest()[:6], 16)


# ---------------------------------------------------------------- programs
def _tool(rng: np.random.Generator, number: int) -> Any:
    from machine.centre.tools import MagazineTool

    d = float(rng.uniform(6e-3, 20e-3))
    return MagazineTool(
        number=number,
        name=f"end mill D{d * 1e3:.0f}",
        n_flutes=int(rng.choice([2, 3, 4])),
        diameter=d,
        helix_deg=float(rng.uniform(20.0, 45.0)),
        eccentricity=float(rng.uniform(2e-6, 12e-6)),
        eccentricity_deg=float(rng.uniform(0.0, 360.0)),
        k_tc=float(rng.uniform(600e6, 800e6)),
        k_rc=float(rng.uniform(150e6, 260e6)),
        k_te=float(rng.uniform(15e3, 30e3)),
        k_re=float(rng.uniform(20e3, 35e3)),
        life=float(rng.uniform(300.0, 600.0)),
    )


def _rpm(rng: np.random.Generator) -> float:
    lo, hi = RPM_RANGE
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def _cuts(rng: np.random.Generator, tool: Any, rpm: float, line: int, n_cuts: int,
          seconds: tuple[float, float]) -> list[Any]:  # fmt: skip
    """Approach, plunge, cut along X or Y, retract: ``n_cuts`` times."""
    from machine.centre.program import Block, Cut, feed_for

    mm = 1e-3
    out = []
    for _ in range(n_cuts):
        fz = float(rng.uniform(0.03, 0.12)) * mm
        ap = float(rng.uniform(0.5, 4.0)) * mm
        cut = Cut(ap, float(rng.uniform(0.1, 1.0)), down_milling=bool(rng.random() < 0.5))
        v = feed_for(tool, rpm, fz)
        length = min(v * float(rng.uniform(*seconds)) + tool.diameter, 0.4)
        x0, y0 = float(rng.uniform(0.0, 0.1)), float(rng.uniform(0.0, 0.1))
        along_x = bool(rng.random() < 0.5)
        end = (x0 + length, y0) if along_x else (x0, y0 + length)
        out += [
            Block(line, "rapid", (x0, y0, 0.02)),
            Block(line + 1, "feed", (x0, y0, -ap), feed=2000 * mm / 60.0),
            Block(line + 2, "feed", (*end, -ap), feed=v, cut=cut),
            Block(line + 3, "rapid", (*end, 0.02)),
        ]
        line += 10
    return out


def event_program(rng: np.random.Generator) -> tuple[Any, list[int]]:
    """One tool, two cuts (1.5-3 s each) at one spindle speed; the cut lines."""
    from machine.centre.program import Block, Program

    t = _tool(rng, 1)
    rpm = _rpm(rng)
    blocks = [
        Block(10, "tool_change", tool=1, seconds=0.5),
        Block(20, "spindle", rpm=rpm, seconds=0.2),
        *_cuts(rng, t, rpm, 100, 2, (1.5, 3.0)),
        Block(900, "end", seconds=0.5),
    ]
    prog = Program(f"O{int(rng.integers(3000, 9999))}", tuple(blocks), (t,), start=(0, 0, 0.1))
    return prog, [b.line for b in blocks if b.cut is not None]


def free_program(rng: np.random.Generator) -> Any:
    """Three tools, each at its own speed, one or two cuts (1-4 s) each."""
    from machine.centre.program import Block, Program

    tools = tuple(_tool(rng, n) for n in (1, 2, 3))
    blocks: list[Any] = []
    for t in tools:
        rpm = _rpm(rng)
        base = 1000 * t.number
        blocks += [
            Block(base, "tool_change", tool=t.number, seconds=0.5),
            Block(base + 10, "spindle", rpm=rpm, seconds=0.2),
            *_cuts(rng, t, rpm, base + 100, int(rng.integers(1, 3)), (1.0, 4.0)),
        ]
    blocks.append(Block(9000, "end", seconds=0.5))
    return Program(f"O{int(rng.integers(3000, 9999))}", tuple(blocks), tools, start=(0, 0, 0.1))


# ---------------------------------------------------------------- the signals
class _AxisForce:
    r"""One feed axis' process force from its trace.

    A semi-closed axis (Y) is one mass: seed 000's motor-side disturbance observer on its
    current and encoder, :math:`F = K_f i - m\,a - b\,v - F_c \tanh(v / v_s)`. The X
    table (two inertias: encoder and linear scale) takes the load-side relation, the
    ball screw's force from its twist: :math:`F = k (q_m - q_l) - m_L a_L - b_L v_L - F_{cL}
    \tanh(v_L / v_s)` (stiff: 0.65 N per encoder count; no motor-side friction or mode
    in it). Every signal through the rate's Q(s).
    """

    def __init__(self, ax: Any, blank: float, ts: float) -> None:
        from estimators.force_observer import ObserverParams, TorsionEstimator, q_cutoff

        twist = ax.kind == "two_inertia"
        m = ax.total_mass(blank)
        self.kf = ax.force_constant
        self.twist = twist
        if twist:
            self.b, self.fc, self.m_l = ax.load_viscous, ax.load_coulomb, ax.load(blank)
            op = ObserverParams(
                J_M=ax.motor_mass, B_M=ax.motor_viscous / ax.p**2, F_CM=ax.motor_coulomb / ax.p,
                K=ax.stiffness, sample_time=ts, encoder_resolution=ax.encoder_quantum,
                q_hz=q_cutoff(ts), mix="twist",
            )  # fmt: skip
        else:
            self.b = ax.motor_viscous / ax.p**2 + ax.load_viscous
            self.fc = ax.motor_coulomb / ax.p + ax.load_coulomb
            self.m_l = 0.5 * m
            op = ObserverParams(
                J_M=0.5 * m, B_M=0.0, F_CM=0.0, K=1e15, sample_time=ts,
                encoder_resolution=ax.encoder_quantum, q_hz=q_cutoff(ts),
                err3_J_M=0.0, err3_B_M=0.0, err3_K=0.0, err3_F_CM=0.0,
            )  # fmt: skip
        self.est = TorsionEstimator(op)
        self.state = self.est.initial_state()

    def __call__(self, i_m: Any, q_m: Any, q_l: Any) -> Any:
        self.state, r = self.est.step(self.state, i_m * self.kf, q_m, q_l if self.twist else q_m)
        fric = self.b * r.vel_l + self.fc * np.tanh(r.vel_l / _V_SMOOTH)
        return r.t_s - self.m_l * r.acc_l - fric


class Watch:
    """One trace rate of one machine: the trace, the signals, the two monitors.

    :meth:`feed` takes each simulated chunk; the alarms (with the signal set, the trace
    sample and the block) accumulate in :attr:`alarms`.
    """

    def __init__(self, machine: Any, rate: float) -> None:
        from estimators.filters import lowpass
        from estimators.force_observer import q_cutoff
        from estimators.monitoring.process import MonitorParams, ProcessMonitor
        from estimators.monitoring.spindle_power import IdlePower, IdlePowerParams
        from machine.centre.trace import CncTrace, TraceParams

        self.rate = rate
        self.trace = CncTrace(TraceParams(rate, "sample"), machine.sample_time)
        self.tstate = self.trace.initial_state()
        ts = 1.0 / rate
        self.ts = ts
        p = machine.params
        self.axes = [_AxisForce(a, machine.blank, ts) for a in p.axes[:2]]
        self.kt = p.spindle.torque_constant
        self.j_sp = p.spindle.inertia
        self.w_prev = math.nan
        q = lowpass(q_cutoff(ts), ts)
        self.q_sp = (q.b, q.a)
        self.z_sp = np.zeros(q.order)
        self.idle = IdlePower(IdlePowerParams(sample_time=ts))
        self.istate = self.idle.initial_state()
        tools = machine.program.tools
        self.radius = np.zeros(max(t.number for t in tools) + 1)
        for t in tools:
            self.radius[t.number] = t.radius
        self.cutting = cutting_lines(machine.program)
        mp = MonitorParams(sample_time=ts, teach_parts=TEACH_PARTS)
        self.mon = {s: ProcessMonitor(mp) for s in MONITORS}
        self.mstate = {s: self.mon[s].initial_state() for s in MONITORS}
        self.psi = 0.0
        self.n = 0  # trace samples fed
        self.last = (-1, -1)  # (part, line) of the block being fed
        #: trace samples per (part, line) executed
        self.block_n: dict[tuple[int, int], int] = {}
        self.alarms: list[dict[str, Any]] = []
        #: trace index of each event's first sample, by event time
        self.events: list[tuple[int, Any]] = []
        #: first trace sample at or after ``watch_from`` where f > extreme, per monitor
        self.watch_from: int | None = None
        self.crossed: dict[str, int] = {}
        self.worst = {s: {"f_over_extreme": 0.0, "pattern_over_limit": 0.0} for s in MONITORS}
        self.mean_over_lower = {s: math.inf for s in MONITORS}

    def signals(self, tr: Any) -> dict[str, tuple[Any, Any]]:
        """``{monitor: (fx, fy)}`` of a trace record."""
        from scipy.signal import lfilter

        w = tr.signal("S.speed") * (math.pi / 30.0)
        w0 = w[0] if math.isnan(self.w_prev) else self.w_prev
        dw = np.diff(w, prepend=w0) / self.ts
        self.w_prev = float(w[-1])
        # the motor's torque less what accelerates the rotor: the load on the spindle
        p_m = (self.kt * tr.signal("S.current") - self.j_sp * dw) * w
        self.istate, irec = self.idle.step(self.istate, tr.signal("S.speed"), p_m)
        with np.errstate(invalid="ignore", divide="ignore"):
            t_cut = np.where((np.abs(w) > 10.0) & np.isfinite(irec.cutting), irec.cutting / w, 0.0)
        t_cut, self.z_sp = lfilter(*self.q_sp, t_cut, zi=self.z_sp)
        r = self.radius[np.clip(tr.tool, 0, len(self.radius) - 1)]
        f_sp = np.where((r > 0.0) & np.isfinite(t_cut), t_cut / np.where(r > 0, r, 1.0), 0.0)
        fx, fy = (
            af(tr.signal(f"{a}.i_m"), tr.signal(f"{a}.q_m"), tr.signal(f"{a}.q_l"))
            for a, af in zip("XY", self.axes, strict=True)
        )
        return {"spindle": (f_sp, np.zeros_like(f_sp)), "axes": (fx, fy)}

    def feed(self, rec: Any) -> None:
        self.tstate, tr = self.trace.export(self.tstate, rec)
        if tr.n == 0:
            return
        for e, j in zip(tr.events, tr.trace_index, strict=True):
            self.events.append((self.n + j, e))
        sig = self.signals(tr)
        dpsi = tr.signal("S.speed") * (math.pi / 30.0) * self.ts
        psi = np.mod(self.psi + np.cumsum(dpsi), 2.0 * math.pi)
        self.psi = float(psi[-1])
        keys = np.stack([tr.part, tr.line])
        cuts = np.flatnonzero(np.any(keys[:, 1:] != keys[:, :-1], axis=0)) + 1
        for a, b in zip([0, *cuts], [*cuts, tr.n], strict=True):
            key = (int(tr.part[a]), int(tr.line[a]))
            new = key != self.last
            self.last = key
            self.block_n[key] = self.block_n.get(key, 0) + (b - a)
            ovr = float(tr.override[a])
            kw: dict[str, Any] = {
                "tool": int(tr.tool[a]), "program": tr.program, "line": key[1],
                "new_block": new, "override": ovr if ovr > 0.0 else 1.0,
                "cutting": self.cutting.get(key[1], True),
            }  # fmt: skip
            for s in MONITORS:
                fx, fy = sig[s]
                self._step(s, (fx[a:b], fy[a:b], psi[a:b]), kw, self.n + a, key)
        self.n += tr.n

    def _step(
        self, s: str, xyp: tuple[Any, Any, Any], kw: dict[str, Any], k0: int, key: tuple[int, int]
    ) -> None:
        """One block of one signal set through its monitor (``xyp``: the two force
        signals and the spindle angle; ``kw``: the block's identities)."""
        m = self.mon[s].step(self.mstate[s], *xyp, **kw)
        self._note(s, m, k0, key)

    def _note(self, s: str, m: Any, k0: int, key: tuple[int, int]) -> None:
        for al in m.alarms:
            self.alarms.append(
                {"set": s, "detector": str(al.detector), "k": int(al.sample), "part": key[0],
                 "line": key[1]}
            )  # fmt: skip
        if self.watch_from is not None and s not in self.crossed:
            over = np.flatnonzero(m.f > m.extreme)
            over = over[k0 + over >= self.watch_from]
            if over.size:
                self.crossed[s] = k0 + int(over[0])
        if m.teaching:
            return
        w = self.worst[s]
        with np.errstate(invalid="ignore", divide="ignore"):
            w["f_over_extreme"] = max(w["f_over_extreme"],
                                      float(np.nanmax(m.f / m.extreme, initial=0.0)))  # fmt: skip
            w["pattern_over_limit"] = max(
                w["pattern_over_limit"], float(np.nanmax(m.pattern / m.pattern_limit, initial=0.0))
            )
            ok = np.isfinite(m.pattern_limit) & np.isfinite(m.f_mean) & (m.lower > 0)
            if ok.any():
                v = float(np.min(m.f_mean[ok] / m.lower[ok]))
                self.mean_over_lower[s] = min(self.mean_over_lower[s], v)

    def time_of(self, k: int) -> float:
        """The trace sample's time [s] (its cycle's last simulated sample)."""
        f = self.trace.factor
        return ((k + 1) * f - 1) * self.trace.sample_time


def _run_parts(machine: Any, state: Any, watches: Sequence[Watch], parts: int) -> Any:
    """Simulate until ``parts`` more parts are done, every chunk into every watch."""
    end = state.part + parts
    while state.part < end:
        state, rec = machine.step(state, CHUNK)
        for w in watches:
            w.feed(rec)
    return state


# ---------------------------------------------------------------- cases
def run_event(case: CentreCase) -> dict[str, Any]:
    """Teach on ``TEACH_PARTS`` parts at 100 %, then one part with the event; per rate
    and signal set: detected, the delay in samples, in time and in revolutions."""
    from machine.centre.sim import MachiningCentre
    from machine.process import ProcessEvent

    t0 = time.perf_counter()
    rng = np.random.default_rng([32, _code(case.kind), case.seed])
    program, cut_lines = event_program(rng)
    line = int(rng.choice(cut_lines))
    tool = program.tools[0]
    size = float(rng.uniform(*SIZES[case.kind]))
    frac = float(rng.uniform(0.2, 0.8))
    if case.kind == ProcessEventKind.MISSING_TOOL and rng.random() < 0.5:
        frac = 0.0  # no tool from the block's start
    ev = ProcessEvent(case.kind, TEACH_PARTS, line, frac, size, int(rng.integers(tool.n_flutes)))
    machine = MachiningCentre(program=program, events=[ev], override_prob=0.0)
    state = machine.initial_state(int(rng.integers(2**31)))
    watches = [Watch(machine, r) for r in RATES]
    state = _run_parts(machine, state, watches, TEACH_PARTS)
    machine.override_prob = 0.3
    rpm = next(b.rpm for b in program.blocks if b.kind == "spindle")
    res: dict[str, Any] = {
        **asdict(case), "size_value": size, "rpm": rpm, "flutes": tool.n_flutes,
        "line": line, "diameter": tool.diameter,
    }  # fmt: skip
    for w in watches:
        w.watch_from = w.n  # the collision's crossing is looked for in the event part only
    state = _run_parts(machine, state, watches, 1)
    for w in watches:
        res[f"{w.rate:g}"] = _score(w, case.kind, line, rpm)
    res["elapsed"] = time.perf_counter() - t0
    return res


def _score(w: Watch, kind: str, line: int, rpm: float) -> dict[str, Any]:
    k_ev, truth = next((k, e) for k, e in w.events if e.line == line)
    spr = 60.0 / rpm * w.rate
    block_s = w.block_n.get((TEACH_PARTS, line), 0) * w.ts
    out: dict[str, Any] = {"k_event": k_ev, "samples_per_rev": spr, "block_s": block_s}
    for s in SETS:
        mons = MONITORS if s == "both" else (s,)
        mine = [a for a in w.alarms if a["set"] in mons]
        pre = [a for a in mine if a["k"] < k_ev and a["part"] >= TEACH_PARTS]
        pre += [a for a in mine if a["part"] < TEACH_PARTS]
        hits = [a for a in mine if a["detector"] == kind and a["k"] >= k_ev and a["line"] == line]
        r: dict[str, Any] = {
            "detected": bool(hits), "pre_alarms": len(pre),
            "others": sorted({a["detector"] for a in mine if a["k"] >= k_ev} - {kind}),
        }  # fmt: skip
        if hits:
            k_al = min(a["k"] for a in hits)
            r["delay_samples"] = k_al - k_ev
            r["delay_s"] = w.time_of(k_al) - truth.t
            r["delay_revs"] = r["delay_s"] * rpm / 60.0
            r["delay_blocks"] = r["delay_s"] / block_s if block_s > 0 else math.nan
            crossed = [w.crossed[m] for m in mons if m in w.crossed and w.crossed[m] <= k_al]
            if kind == ProcessEventKind.COLLISION and crossed:
                r["delay_from_estimate_s"] = (k_al - min(crossed)) * w.ts
        out[s] = r
    return out


def run_free(case: CentreCase) -> dict[str, Any]:
    """Event-free hours after the teach-in: every alarm is false."""
    from machine.centre.sim import MachiningCentre

    t0 = time.perf_counter()
    rng = np.random.default_rng([32, _code("none"), case.seed])
    program = free_program(rng)
    machine = MachiningCentre(program=program, override_prob=0.0)
    state = machine.initial_state(int(rng.integers(2**31)))
    watches = [Watch(machine, r) for r in RATES]
    state = _run_parts(machine, state, watches, TEACH_PARTS)
    machine.override_prob = 0.2
    start = [len(w.alarms) for w in watches]
    t_start = state.k * machine.sample_time
    while state.k * machine.sample_time - t_start < case.hours * 3600.0:
        state = _run_parts(machine, state, watches, 1)
    watched = state.k * machine.sample_time - t_start
    res: dict[str, Any] = {
        **asdict(case),
        "watched_h": watched / 3600.0,
        "tool_replacements": state.tool_changes,
        "parts": state.part,
    }
    for w, a0 in zip(watches, start, strict=True):
        al = w.alarms[a0:]
        res[f"{w.rate:g}"] = {
            "alarms": {
                s: {d: sum(1 for a in al if a["set"] in (MONITORS if s == "both" else (s,))
                           and a["detector"] == d) for d in ProcessEventKind}
                for s in SETS
            },
            "any": {s: sum(1 for a in al if a["set"] in (MONITORS if s == "both" else (s,)))
                    for s in SETS},
            "worst": w.worst,
            "mean_over_lower": w.mean_over_lower,
        }  # fmt: skip
    res["elapsed"] = time.perf_counter() - t0
    return res


def run_centre_case(case: CentreCase) -> dict[str, Any]:
    return run_free(case) if case.kind == "none" else run_event(case)


__all__ = ["RATES", "SETS", "CentreCase", "Watch", "cutting_lines", "event_program",
           "free_program", "run_centre_case", "run_event", "run_free"]  # fmt: skip
