r"""Process monitoring: detection rates, delays and false alarms, with 95 % intervals.

A Monte Carlo over seeds that vary the cut (tool: flutes, diameter, helix, runout; cut:
spindle speed, feed per tooth, depths, up/down milling; drive noise: scale resolution,
current noise, observer mass error; event time and size). Per event kind
(:data:`machine.process.EVENT_KINDS`) and size (``clear``, ``edge`` of detectability):

1. teach :class:`estimators.monitoring.process.ProcessMonitor` on the first good parts of a
   random two-cut program (tool 1; air, cut, air, cut, air);
2. cut one more part with the event injected in a cut block, the force estimated from
   the X/Y drives by the observers (:class:`harness.eccentricity_loop.
   ObserverForceSource`), never the true force;
3. score: the right detector's first alarm at or after the event's first sample, within
   the event's block; its delay, sample-exact.

Event-free hours: a three-tool program with spindle steps, tool changes, air moves with
entries and exits, a new workpiece (depth spread) every part, feed overrides now and then,
wear going on and worn tools replaced by new instances (another runout); every alarm
after the teach-in is false.

Rates carry one-sided 95 % bounds (:mod:`server.experiments.confidence`, the one place
every reproduction takes them from): a share its Clopper-Pearson bounds, a false-alarm
rate per hour the exact Poisson (Garwood) upper bound, a delay quantile the
distribution-free upper bound (order statistics). A check holds only when the bound on
the target's side meets the target.

The machining centre (issue 32, :mod:`._centre_monitoring`, rows by :mod:`._centre_rows`):
each seed simulated once at 10 kHz and exported as the CNC's trace at 5 kHz, 1 kHz and
500 Hz, each trace watched on the spindle alone, the axes alone and both, so every
comparison is paired; rows ``<kind>.clear.<set>.<what>_at_<rate>hz``.

The full run keeps each finished case in a JSON-lines cache keyed by the hash of the code
it depends on (:func:`cache_path`, :func:`centre_cache_path`), so an interrupted run
resumes.
"""

from __future__ import annotations

import hashlib
import json
import math
import multiprocessing as mp
import os
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from common.event_kinds import ProcessEventKind
from server.experiments.confidence import (
    proportion_bounds,
    quantile_upper,
    rate_upper,
)
from server.experiments.reproduction import Check, Reproduction, Row

if TYPE_CHECKING:
    pass

NAME = "process-monitoring"
SOURCE = "issue 21 (process monitoring on seed 003's feed drives); targets from the issue"

WORKERS = 2
#: events per kind at the clear size: >= 299 with no miss give a one-sided 95 % lower
#: bound of 0.99 (0.05 ** (1 / 299)); 370 leave room for one miss (0.9873 at 369/370)
N_CLEAR = 370
N_EDGE = 100
#: breakages with the eccentricity canceller running
N_CANCELLER = 60
#: event-free simulated hours (0 alarms in 38 h: one-sided upper bound 3.00 / 38 = 0.079
#: per hour; 30 h would be the least that reaches 0.1)
FREE_HOURS = 38
LONG_RUNS = 2
LONG_HOURS = 10.0
#: targets of the issue
TARGET_DETECTION = 0.99
TARGET_BREAKAGE_REVS = 2.0
TARGET_COLLISION_S = 5e-3
TARGET_FALSE_PER_HOUR = 0.1
TEACH_PARTS = 5

_SIZES: dict[tuple[str, str], tuple[float, float]] = {
    # breakage: radius lost [m] (clear: the tooth is gone; edge: a chip of the edge, a
    # share of the feed per tooth); collision: feed multiplier; missing: engagement lost
    (ProcessEventKind.BREAKAGE, "clear"): (0.2e-3, 0.6e-3),
    (ProcessEventKind.BREAKAGE, "edge"): (0.15, 0.3),
    (ProcessEventKind.COLLISION, "clear"): (4.0, 8.0),
    (ProcessEventKind.COLLISION, "edge"): (2.3, 2.8),
    (ProcessEventKind.MISSING_TOOL, "clear"): (1.0, 1.0),
    (ProcessEventKind.MISSING_TOOL, "edge"): (0.6, 0.8),
}


@dataclass(frozen=True)
class Case:
    """One seed: an event (kind, size class) or an event-free run (kind ``none``)."""

    kind: str
    size: str
    seed: int
    hours: float = 0.0


def _tool(rng: np.random.Generator, number: int, wear_per_s: float) -> Any:
    from machine.process import Tool

    nf = int(rng.choice([2, 3, 4]))
    d = float(rng.uniform(6e-3, 16e-3))
    return Tool(
        number=number,
        n_flutes=nf,
        diameter=d,
        helix_deg=float(rng.uniform(20.0, 45.0)),
        eccentricity=float(rng.uniform(2e-6, 15e-6)),
        eccentricity_deg=float(rng.uniform(0.0, 360.0)),
        k_tc=float(rng.uniform(600e6, 800e6)),
        k_rc=float(rng.uniform(150e6, 260e6)),
        k_te=float(rng.uniform(15e3, 30e3)),
        k_re=float(rng.uniform(20e3, 35e3)),
        wear_per_s=wear_per_s,
        wear_limit=float(rng.uniform(0.6, 1.0)),
    )


def _cut(rng: np.random.Generator, line: int, tool: Any, seconds: tuple[float, float]) -> Any:
    from machine.process import ProgramBlock

    rpm = float(rng.uniform(900.0, 2400.0))
    fz = float(rng.uniform(30e-6, 100e-6))
    ap = float(rng.uniform(0.5e-3, 2.5e-3))
    ae = float(rng.uniform(0.1, 1.0))
    v = fz * tool.n_flutes * rpm / 60.0
    dur = float(rng.uniform(*seconds))
    return ProgramBlock(
        line,
        tool.number,
        True,
        v * dur + tool.diameter,
        spindle_rpm=rpm,
        feed_per_tooth=fz,
        axial_depth=ap,
        radial_immersion=ae,
        down_milling=bool(rng.random() < 0.5),
    )


def _air(rng: np.random.Generator, line: int, tool: Any, rpm: float) -> Any:
    from machine.process import ProgramBlock

    return ProgramBlock(
        line,
        tool.number,
        False,
        float(rng.uniform(4e-3, 12e-3)),
        spindle_rpm=rpm,
        air_speed=float(rng.uniform(0.01, 0.03)),
    )


def _event_program(rng: np.random.Generator) -> Any:
    from machine.process import PartProgram

    t = _tool(rng, 1, float(rng.uniform(0.0, 5e-3)))
    c1 = _cut(rng, 20, t, (1.5, 3.0))
    c2 = _cut(rng, 40, t, (1.5, 3.0))
    blocks = (
        _air(rng, 10, t, c1.spindle_rpm),
        c1,
        _air(rng, 30, t, c2.spindle_rpm),
        c2,
        _air(rng, 50, t, c2.spindle_rpm),
    )
    return PartProgram(f"O{int(rng.integers(1000, 9999))}", blocks, (t,))


def _free_program(rng: np.random.Generator) -> Any:
    from machine.process import PartProgram

    tools = tuple(_tool(rng, n, float(rng.uniform(2e-3, 6e-3))) for n in (1, 2, 3))
    blocks = []
    line = 10
    for t in tools:
        for _ in range(int(rng.integers(1, 3))):
            c = _cut(rng, line + 10, t, (1.0, 4.0))
            blocks += [_air(rng, line, t, c.spindle_rpm), c]
            line += 20
    return PartProgram(f"O{int(rng.integers(1000, 9999))}", tuple(blocks), tools)


def _noise(rng: np.random.Generator) -> dict[str, float]:
    return {
        "resolution": float(10 ** rng.uniform(-9, -8)),
        "current_noise": float(rng.uniform(0.002, 0.02)),
        "mass_error": float(rng.uniform(-0.03, 0.03)),
    }


def _setup(program: Any, rng: np.random.Generator, noise: dict[str, float], **kw: Any) -> Any:
    from estimators.monitoring.process import MonitorParams, ProcessMonitor
    from harness.eccentricity_loop import ObserverForceSource
    from machine.process import ProcessMachine

    machine = ProcessMachine(program, rng=rng, **kw)
    obs = ObserverForceSource(
        machine.drives,
        q_hz=1000.0,
        rng=np.random.default_rng(rng.integers(2**32)),
        **noise,
    )
    mon = ProcessMonitor(MonitorParams(sample_time=machine.sample_time, teach_parts=TEACH_PARTS))
    return machine, obs, mon, mon.initial_state()


def _watch(obs: Any, mon: Any, state: Any, r: Any, new_block: bool = True) -> Any:
    """The drives' force estimate of a block record through the monitor: ``(fx, record)``."""
    fx, fy = obs(r)
    rec = mon.step(
        state,
        fx,
        fy,
        r.psi,
        tool=r.tool,
        program=r.program,
        line=r.line,
        new_block=new_block,
        override=r.override,
    )
    return fx, rec


def _teach(machine: Any, obs: Any, mon: Any, state: Any) -> int:
    """Cut parts until every block is taught; returns the parts cut."""
    parts = 0
    while True:
        for r in machine.run_part():
            _watch(obs, mon, state, r)
        parts += 1
        used = state["key_tool"] >= 0
        if np.all(state["parts"][used] >= TEACH_PARTS) or parts > 50:
            return parts


def run_event_case(case: Case) -> dict[str, Any]:
    """Teach, then one part with the event; the detector's verdict and delay."""
    from machine.process import ProcessEvent

    t_start = time.perf_counter()
    rng = np.random.default_rng([21, _code(case.kind), _code(case.size), case.seed])
    program = _event_program(rng)
    machine, obs, mon, state = _setup(program, rng, _noise(rng), override_prob=0.0)
    _teach(machine, obs, mon, state)
    machine.override_prob = 0.3
    line = int(rng.choice([20, 40]))
    blk = next(b for b in program.blocks if b.line == line)
    tool = program.tool(blk.tool)
    lo, hi = _SIZES[(case.kind, case.size)]
    size = float(rng.uniform(lo, hi))
    if case.kind == ProcessEventKind.BREAKAGE and case.size == "edge":
        size *= blk.feed_per_tooth  # a chip: a share of the feed per tooth
    frac = float(rng.uniform(0.2, 0.8))
    if case.kind == ProcessEventKind.MISSING_TOOL and rng.random() < 0.5:
        frac = 0.0  # no tool from the block's start (not loaded at the tool change)
    ev = ProcessEvent(case.kind, machine.part, line, frac, size, int(rng.integers(tool.n_flutes)))
    machine.events = [ev]
    override = 1.0 if rng.random() < 0.7 else float(rng.choice([0.9, 1.1]))
    pre_alarms = 0
    res: dict[str, Any] = {
        **asdict(case),
        "size_value": size,
        "rpm": blk.spindle_rpm,
        "flutes": tool.n_flutes,
        "detected": False,
    }
    for b in program.blocks:
        recs = machine.run_block(b, override=override)
        r = recs[0]
        _, mrec = _watch(obs, mon, state, r)
        if b.line != line:
            pre_alarms += len(mrec.alarms)
            continue
        truth = r.events[0]
        k_ev = truth.sample - r.k0
        base = int(state["samples"][0]) - r.n
        pre_alarms += sum(1 for a in mrec.alarms if a.sample - base < k_ev)
        hits = [a for a in mrec.alarms if a.detector == case.kind and a.sample - base >= k_ev]
        others = sorted({a.detector for a in mrec.alarms if a.sample - base >= k_ev} - {case.kind})
        ts = machine.sample_time
        res.update(
            block_s=r.n * ts,
            event_t=truth.t,
            other_detectors=others,
            override=r.override,
        )
        if hits:
            k_al = hits[0].sample - base
            res.update(detected=True, delay_s=(k_al - k_ev) * ts)
            res["delay_revs"] = res["delay_s"] * blk.spindle_rpm / 60.0
            res["delay_blocks"] = res["delay_s"] / (r.n * ts)
            if case.kind == ProcessEventKind.COLLISION:
                ex = mrec.extreme
                est = np.flatnonzero(mrec.f[k_ev:] > ex[k_ev:])
                true = np.flatnonzero(np.hypot(r.fx, r.fy)[k_ev:] > ex[k_ev:])
                if est.size:
                    res["delay_from_estimate_s"] = (k_al - k_ev - int(est[0])) * ts
                if true.size:
                    res["delay_from_true_s"] = (k_al - k_ev - int(true[0])) * ts
        break
    res["pre_alarms"] = pre_alarms
    res["elapsed"] = time.perf_counter() - t_start
    return res


def _code(s: str) -> int:
    return int(hashlib.sha256(s.encode()).hexdigest()[:6], 16)


def run_free_case(case: Case) -> dict[str, Any]:
    """Event-free hours: every alarm after the teach-in is false."""
    from estimators.monitoring.process import DETECTORS

    t_start = time.perf_counter()
    rng = np.random.default_rng([21, _code("none"), case.seed])
    program = _free_program(rng)
    machine, obs, mon, state = _setup(program, rng, _noise(rng), override_prob=0.2)
    _teach(machine, obs, mon, state)
    t0 = machine.t
    alarms = {d: 0 for d in DETECTORS}
    worst = {"f_over_extreme": 0.0, "fmean_over_lower": math.inf, "pattern_over_limit": 0.0}
    hourly: list[dict[str, float]] = []
    next_hour = t0 + 3600.0
    hw = dict(worst)
    while machine.t - t0 < case.hours * 3600.0:
        for r in machine.run_part():
            _, m = _watch(obs, mon, state, r)
            for a in m.alarms:
                alarms[a.detector] += 1
            with np.errstate(invalid="ignore", divide="ignore"):
                for key, v in (
                    ("f_over_extreme", np.nanmax(m.f / m.extreme, initial=0.0)),
                    ("pattern_over_limit", np.nanmax(m.pattern / m.pattern_limit, initial=0.0)),
                ):
                    hw[key] = max(hw[key], float(v))
                lo_ok = np.isfinite(m.pattern_limit) & np.isfinite(m.f_mean)
                if lo_ok.any():
                    v = float(np.min(m.f_mean[lo_ok] / m.lower[lo_ok]))
                    hw["fmean_over_lower"] = min(hw["fmean_over_lower"], v)
        if machine.t >= next_hour:
            cut = state["key_tool"] >= 0
            hourly.append(
                {
                    **hw,
                    "gain_min": float(state["gain"][cut].min()),
                    "gain_max": float(state["gain"][cut].max()),
                    "wear_max": max(i.wear for i in machine.instances.values()),
                }
            )
            for k in worst:
                worst[k] = max(worst[k], hw[k]) if k != "fmean_over_lower" else min(worst[k], hw[k])
            hw = {"f_over_extreme": 0.0, "fmean_over_lower": math.inf, "pattern_over_limit": 0.0}
            next_hour += 3600.0
    for k in worst:
        worst[k] = max(worst[k], hw[k]) if k != "fmean_over_lower" else min(worst[k], hw[k])
    return {
        **asdict(case),
        "watched_h": (machine.t - t0) / 3600.0,
        "alarms": alarms,
        "worst": worst,
        "hourly": hourly,
        "tool_replacements": machine.tool_changes,
        "parts": machine.part,
        "elapsed": time.perf_counter() - t_start,
    }


def run_canceller_case(case: Case) -> dict[str, Any]:
    """A tooth breaks while seed 003's eccentricity canceller (ESC) adapts.

    The ESC updates the modulation once per revolution from the X force estimate, in cut
    blocks, during the teach-in and after it; it holds its adaptation in a revolution in
    which the monitor flags ``suspected`` (or after an alarm). Scored as the event cases,
    plus the ESC updates made between the breakage and the alarm.
    """
    from estimators.esc import ExtremumSeekingController, harmonic_cost
    from machine.process import ProcessEvent

    t_start = time.perf_counter()
    rng = np.random.default_rng([21, _code("canceller"), case.seed])
    program = _event_program(rng)
    machine, obs, mon, state = _setup(program, rng, _noise(rng), override_prob=0.0)
    esc = ExtremumSeekingController()
    ts = machine.sample_time
    ctl: dict[str, Any] = {"esc": None, "held": 0, "updates": [], "alarms": [], "latched": False}

    def part() -> None:
        for b in program.blocks:
            spr = max(4, round(60.0 / (b.spindle_rpm * ts)))
            ctl["first"] = True
            ctl["k_block"] = machine.k
            ctl["n_block"] = machine.block_samples(b)
            ctl["latched"] = False

            def on_chunk(r: Any, spr: int = spr) -> None:
                fx, m = _watch(obs, mon, state, r, ctl["first"])
                ctl["first"] = False
                if r.events:
                    ctl["truth"] = r.events[0]
                ctl["alarms"] += m.alarms
                ctl["latched"] = ctl["latched"] or bool(m.alarms)
                if not r.cut or r.n < spr:
                    return
                if m.suspected.any() or ctl["latched"]:
                    ctl["held"] += 1
                    return
                cost = harmonic_cost(fx, r.psi)
                if ctl["esc"] is None:
                    # start in the middle of a cut (the cost of a full engagement without
                    # modulation normalises the ESC's gains, as in the seed 003 loop)
                    if cost <= 0.0 or r.k0 - ctl["k_block"] < 0.5 * ctl["n_block"]:
                        return
                    ctl["esc"] = esc.initial_state(cost_ref=cost)
                else:
                    ctl["esc"], _ = esc.step(ctl["esc"], fx, r.psi, r.n * ts, cost=cost)
                machine.set_modulation(ctl["esc"].a_um * 1e-6, math.radians(ctl["esc"].theta_deg))
                ctl["updates"].append(r.k0 + r.n)
                ctl["a_max"] = max(ctl.get("a_max", 0.0), abs(ctl["esc"].a_um))

            machine.run_block(b, chunk=spr, on_chunk=on_chunk)
        machine.part += 1

    for _ in range(50):
        part()
        used = state["key_tool"] >= 0
        if np.all(state["parts"][used] >= TEACH_PARTS):
            break
    pre = len(ctl["alarms"])
    line = int(rng.choice([20, 40]))
    blk = next(b for b in program.blocks if b.line == line)
    tool = program.tool(blk.tool)
    size = float(rng.uniform(*_SIZES[(ProcessEventKind.BREAKAGE, "clear")]))
    ev = ProcessEvent(
        ProcessEventKind.BREAKAGE,
        machine.part,
        line,
        float(rng.uniform(0.2, 0.8)),
        size,
        int(rng.integers(tool.n_flutes)),
    )
    machine.events = [ev]
    part()
    k_ev = int(ctl["truth"].sample)
    res: dict[str, Any] = {
        **asdict(case),
        "size_value": size,
        "rpm": blk.spindle_rpm,
        "flutes": tool.n_flutes,
        "detected": False,
        "esc_updates": len(ctl["updates"]),
    }
    alarms = ctl["alarms"][pre:]
    res["pre_alarms"] = sum(1 for a in alarms if a.sample < k_ev)
    hits = [
        a
        for a in alarms
        if a.detector == ProcessEventKind.BREAKAGE and a.sample >= k_ev and a.line == line
    ]
    if hits:
        k_al = hits[0].sample
        res.update(detected=True, delay_s=(k_al - k_ev) * ts)
        res["delay_revs"] = res["delay_s"] * blk.spindle_rpm / 60.0
        res["esc_updates_between"] = sum(1 for k in ctl["updates"] if k_ev < k <= k_al)
    res["held_revs"] = ctl["held"]
    res["esc_a_max_um"] = float(ctl.get("a_max", 0.0))
    res["elapsed"] = time.perf_counter() - t_start
    return res


def run_case(case: Case) -> dict[str, Any]:
    if case.kind == "none":
        return run_free_case(case)
    if case.size == "canceller":
        return run_canceller_case(case)
    return run_event_case(case)


def _cases(quick: bool) -> list[Case]:
    n_clear, n_edge, n_esc, hours, per = (
        (4, 2, 2, 0.05, 0.05) if quick else (N_CLEAR, N_EDGE, N_CANCELLER, FREE_HOURS, 1.0)
    )
    if quick:
        out = [Case("none", "", s, per) for s in range(max(1, round(hours / per)))]
    else:
        # two continuous runs of LONG_HOURS (the limits must not drift over a long run),
        # the rest one hour each (more programs, tools and noise levels)
        out = [Case("none", "", 100 + s, LONG_HOURS) for s in range(LONG_RUNS)]
        rest = FREE_HOURS - LONG_RUNS * LONG_HOURS
        out += [Case("none", "", s, per) for s in range(round(rest / per))]
    out += [Case(ProcessEventKind.BREAKAGE, "canceller", s) for s in range(n_esc)]
    for kind in ProcessEventKind:
        out += [Case(kind, "clear", s) for s in range(n_clear)]
        out += [Case(kind, "edge", s) for s in range(n_edge)]
    return out


#: the machining centre (issue 32): clear events per kind (>= 299: a 99 % lower bound with
#: no miss) and event-free hours (>= 30: 0.1 per hour with none), each hour one case
N_CENTRE = 300
CENTRE_HOURS = 30


def centre_cases(quick: bool) -> list[Any]:
    """The machining centre's cases: every kind's events seed by seed, an event-free hour
    after every ten seeds."""
    from server.experiments.reproductions._centre_monitoring import CentreCase

    n, hours, per = (2, 0.02, 0.02) if quick else (N_CENTRE, CENTRE_HOURS, 1.0)
    events = [CentreCase(str(kind), s) for s in range(n) for kind in ProcessEventKind]
    free = [CentreCase("none", s, per) for s in range(max(1, round(hours / per)))]
    # interleaved (an event-free hour after every ten seeds' events), so that a run cut
    # short still has every kind of row
    out: list[Any] = []
    step = 30
    for i in range(max(len(free), math.ceil(len(events) / step))):
        out += events[i * step : (i + 1) * step]
        out += free[i : i + 1]
    return out


def _centre_key(r: Any) -> tuple[str, int, float]:
    if isinstance(r, dict):
        return (str(r["kind"]), int(r["seed"]), float(r["hours"]))
    return (r.kind, r.seed, r.hours)


_CENTRE_CODE = (
    "estimators/monitoring/process.py",
    "estimators/monitoring/spindle_power.py",
    "estimators/force_observer.py",
    "estimators/filters.py",
    "machine",
    "common",
    "server/experiments/reproductions/_centre_monitoring.py",
)


def centre_cache_path() -> Path:
    """The machining centre's case cache, keyed by the hash of the code its cases run."""
    base = os.environ.get("CUTWATCH_CACHE_DIR") or str(Path.home() / ".cache" / "cutwatch")
    return Path(base) / NAME / f"centre-{code_version(_CENTRE_CODE)}.jsonl"


def run_centre(*, quick: bool, progress: bool) -> list[dict[str, Any]]:
    """The machining centre's cases (the full run cached in :func:`centre_cache_path`)."""
    from server.experiments.reproductions._centre_monitoring import run_centre_case

    return run_cases(
        centre_cases(quick),
        progress=progress,
        cache=None if quick else centre_cache_path(),
        fn=run_centre_case,
        key=_centre_key,
        desc=f"{NAME} (machining centre)",
        longest_first=False,
    )


_CODE = (
    "estimators/monitoring/process.py",
    "machine",
    "common",
    "harness/eccentricity_loop.py",
)


def code_version(code: tuple[str, ...] | None = None) -> str:
    """Hash of the sources a case's outcome depends on (default: the issue-21 machine's)."""
    root = Path(__file__).resolve().parents[3]
    h = hashlib.sha256()
    own = "server/experiments/reproductions/process_monitoring.py"
    rels = (*_CODE, own) if code is None else code
    for rel in rels:
        p = root / rel
        for f in sorted(p.rglob("*.py")) if p.is_dir() else [p]:
            h.update(str(f.relative_to(root)).encode())
            h.update(f.read_bytes())
    return h.hexdigest()[:16]


def cache_path() -> Path:
    """``$CUTWATCH_CACHE_DIR`` or ``~/.cache/cutwatch``, one JSON-lines file per code
    version."""
    base = os.environ.get("CUTWATCH_CACHE_DIR") or str(Path.home() / ".cache" / "cutwatch")
    return Path(base) / NAME / f"{code_version()}.jsonl"


def _ckey(r: Case | dict[str, Any]) -> tuple[str, str, int, float]:
    if isinstance(r, Case):
        return (r.kind, r.size, r.seed, r.hours)
    return (str(r["kind"]), str(r["size"]), int(r["seed"]), float(r["hours"]))


def _init_worker() -> None:
    import warnings

    warnings.simplefilter("ignore")


def run_cases(
    cases: list[Any],
    *,
    progress: bool,
    cache: Path | None,
    fn: Any = None,
    key: Any = None,
    desc: str = NAME,
    longest_first: bool = True,
) -> list[dict[str, Any]]:
    """Run the cases on :data:`WORKERS` processes, resuming from ``cache`` (``fn`` runs a
    case, default :func:`run_case`; ``key`` names a case or a result, default the
    issue-21 machine's)."""
    from tqdm import tqdm

    fn = run_case if fn is None else fn
    key = _ckey if key is None else key
    done: dict[Any, dict[str, Any]] = {}
    if cache is not None and cache.is_file():
        for line in cache.read_text().splitlines():
            try:
                r = json.loads(line)
                done[key(r)] = r
            except (ValueError, KeyError, TypeError):
                continue  # a line cut short by an interrupted run
    results = [done[key(c)] for c in cases if key(c) in done]
    todo = [c for c in cases if key(c) not in done]
    if longest_first:
        # the long event-free cases first, so the two workers finish together
        todo.sort(key=lambda c: -c.hours)
    sink = None
    if cache is not None:
        cache.parent.mkdir(parents=True, exist_ok=True)
        sink = cache.open("a")
        sink.write("\n")  # after an interrupted run's cut line
        if results and progress:
            print(f"{desc}: {len(results)} cases from {cache}", file=sys.stderr)
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    try:
        with tqdm(
            total=len(todo), desc=desc, unit="case", disable=not progress or not todo, leave=False
        ) as bar:
            if len(todo) <= 1:
                it = map(fn, todo)
                for r in it:
                    results.append(r)
                    bar.update(1)
            else:
                with mp.get_context("spawn").Pool(WORKERS, initializer=_init_worker) as pool:
                    for r in pool.imap_unordered(fn, todo, chunksize=1):
                        results.append(r)
                        if sink is not None:
                            sink.write(json.dumps(r) + "\n")
                            sink.flush()
                        bar.update(1)
    finally:
        if sink is not None:
            sink.close()
    return results


#: the unit of each kind's size
_SIZE_UNITS: dict[str, str] = {
    ProcessEventKind.BREAKAGE: "m radius",
    ProcessEventKind.COLLISION: "x feed",
    ProcessEventKind.MISSING_TOOL: "share",
}
_DELAY_TARGETS: dict[str, tuple[str, float, str, str]] = {
    ProcessEventKind.BREAKAGE: (
        "delay_revs",
        TARGET_BREAKAGE_REVS,
        "rev",
        "from the event's first sample",
    ),
    ProcessEventKind.COLLISION: (
        "delay_from_estimate_s",
        TARGET_COLLISION_S,
        "s",
        "from the estimated force crossing the extreme limit",
    ),
    ProcessEventKind.MISSING_TOOL: ("delay_blocks", 1.0, "block", "from the event's first sample"),
}


def _cp(lo: float, hi: float) -> str:
    return f"one-sided 95 % CP bounds {lo:.4f} / {hi:.4f}"


def build(results: list[dict[str, Any]]) -> Reproduction:
    """Rows and checks from the cases."""
    rep = Reproduction(NAME, SOURCE)
    for kind in ProcessEventKind:
        for size in ("clear", "edge"):
            rs = [r for r in results if r["kind"] == kind and r["size"] == size]
            if not rs:
                continue
            _event_rows(rep, kind, size, rs)
    esc = [r for r in results if r["size"] == "canceller"]
    if esc:
        _canceller_rows(rep, esc)
    free = [r for r in results if r["kind"] == "none"]
    if free:
        _false_alarm_rows(rep, free)
        _free_limit_rows(rep, free)
        _free_long_rows(rep, free)
        rep.rows.append(
            Row(
                "free.tool_replacements",
                sum(r["tool_replacements"] for r in free),
                None,
                "tools",
                "worn tools replaced by new instances",
            )
        )
    return rep


def _event_rows(rep: Reproduction, kind: str, size: str, rs: list[dict[str, Any]]) -> None:
    """Detection, misses, alarms before the event and delays of one kind and size of event."""
    n = len(rs)
    k = sum(1 for r in rs if r["detected"])
    lo, hi = proportion_bounds(k, n)
    sv = [r["size_value"] for r in rs]
    unit = _SIZE_UNITS[kind]
    cond = f"{n} events, size {min(sv):.3g}-{max(sv):.3g} {unit}; {_cp(lo, hi)}"
    rep.rows.append(Row(f"{kind}.{size}.detection", k / n, None, "-", cond))
    misses = [r["seed"] for r in rs if not r["detected"]]
    if misses:
        rep.rows.append(
            Row(
                f"{kind}.{size}.misses",
                len(misses),
                None,
                "events",
                "seeds " + ", ".join(map(str, misses[:20])),
            )
        )
    pre = sum(r.get("pre_alarms", 0) for r in rs)
    rep.rows.append(
        Row(
            f"{kind}.{size}.alarms_before_event",
            pre,
            None,
            "alarms",
            "in the watched event parts, before the event",
        )
    )
    key, target, tunit, tcond = _DELAY_TARGETS[kind]
    d = [float(r[key]) for r in rs if r["detected"] and key in r]
    if d:
        med = float(np.median(d))
        p95 = float(np.percentile(d, 95))
        p95_hi = quantile_upper(d, 0.95)
        rep.rows.append(Row(f"{kind}.{size}.delay_median", med, None, tunit, tcond))
        rep.rows.append(
            Row(
                f"{kind}.{size}.delay_p95",
                p95,
                None,
                tunit,
                f"one-sided 95 % upper bound {p95_hi:.4g} {tunit}; target {target:g}",
            )
        )
    if kind == ProcessEventKind.COLLISION:
        dt = [float(r["delay_from_true_s"]) for r in rs if "delay_from_true_s" in r]
        if dt:
            rep.rows.append(
                Row(
                    f"collision.{size}.delay_from_true_p95",
                    float(np.percentile(dt, 95)),
                    None,
                    "s",
                    "from the true force crossing the limit",
                )
            )
    if size == "clear":
        rep.checks.append(
            Check(
                f"{kind}.clear.detection_lower_95 >= 0.99",
                lo >= TARGET_DETECTION,
                lo,
                TARGET_DETECTION,
            )
        )
        if d:
            rep.checks.append(
                Check(
                    f"{kind}.clear.delay_median <= {target:g} {tunit}",
                    med <= target,
                    med,
                    target,
                )
            )
            rep.checks.append(
                Check(
                    f"{kind}.clear.delay_p95_upper_95 <= {target:g} {tunit}",
                    p95_hi <= target,
                    p95_hi,
                    target,
                )
            )


def _canceller_rows(rep: Reproduction, esc: list[dict[str, Any]]) -> None:
    """Tooth breakages with the ESC adapting: detection, delay and the ESC held until the alarm."""
    n = len(esc)
    k = sum(1 for r in esc if r["detected"])
    lo, hi = proportion_bounds(k, n)
    fl = {f: [r for r in esc if r["flutes"] == f] for f in (2, 3, 4)}
    per = ", ".join(f"{f} flutes {sum(r['detected'] for r in v)}/{len(v)}" for f, v in fl.items())
    rep.rows.append(
        Row(
            "breakage.canceller.detection",
            k / n,
            None,
            "-",
            f"{n} tooth breakages with the ESC adapting; {_cp(lo, hi)}; {per}",
        )
    )
    d = [float(r["delay_revs"]) for r in esc if r["detected"]]
    if d:
        rep.rows.append(
            Row(
                "breakage.canceller.delay_median",
                float(np.median(d)),
                None,
                "rev",
                "from the event's first sample",
            )
        )
    between = [int(r["esc_updates_between"]) for r in esc if r["detected"]]
    rep.rows.append(
        Row(
            "breakage.canceller.esc_updates_before_alarm",
            max(between, default=0),
            None,
            "updates",
            "largest number of ESC updates between a breakage and its alarm (held while suspected)",
        )
    )
    rep.rows.append(
        Row(
            "breakage.canceller.pre_alarms",
            sum(r["pre_alarms"] for r in esc),
            None,
            "alarms",
            "in the event parts before the breakage",
        )
    )
    rep.checks.append(
        Check(
            "breakage.canceller.esc_held_until_alarm",
            max(between, default=0) == 0,
            max(between, default=0),
            0,
        )
    )


def _false_alarm_rows(rep: Reproduction, free: list[dict[str, Any]]) -> None:
    """False alarms per hour of each detector over the event-free hours."""
    hours = float(sum(r["watched_h"] for r in free))
    for det in ProcessEventKind:
        k = int(sum(r["alarms"][det] for r in free))
        hi = rate_upper(k, hours)
        rep.rows.append(
            Row(
                f"false_alarms.{det}",
                k / hours,
                None,
                "per hour",
                f"{k} in {hours:.1f} h event-free; one-sided 95 % upper bound {hi:.4f}",
            )
        )
        rep.checks.append(
            Check(
                f"false_alarms.{det}.upper_95 <= 0.1 per hour",
                hi <= TARGET_FALSE_PER_HOUR,
                hi,
                TARGET_FALSE_PER_HOUR,
            )
        )


def _free_limit_rows(rep: Reproduction, free: list[dict[str, Any]]) -> None:
    """How close the event-free hours came to the limits, and the wear and gain reached."""
    w = [r["worst"] for r in free]
    rep.rows.append(
        Row(
            "free.max_force_over_extreme",
            max(x["f_over_extreme"] for x in w),
            None,
            "-",
            "largest f / extreme limit, all event-free hours",
        )
    )
    rep.rows.append(
        Row(
            "free.min_mean_over_lower",
            min(x["fmean_over_lower"] for x in w),
            None,
            "-",
            "smallest mean force / lower limit where cutting",
        )
    )
    rep.rows.append(
        Row(
            "free.max_pattern_over_limit",
            max(x["pattern_over_limit"] for x in w),
            None,
            "-",
            "largest d / breakage threshold",
        )
    )
    hw = [h for r in free for h in r["hourly"]]
    if hw:
        rep.rows.append(
            Row(
                "free.wear_max",
                max(h["wear_max"] for h in hw),
                None,
                "-",
                "largest edge-coefficient growth reached",
            )
        )
        rep.rows.append(
            Row(
                "free.tracked_gain_max",
                max(h["gain_max"] for h in hw),
                None,
                "-",
                "largest tracked force ratio moving the limits",
            )
        )


def _free_long_rows(rep: Reproduction, free: list[dict[str, Any]]) -> None:
    """The last hour of each long continuous event-free run against its first."""
    for r in (r for r in free if r["hours"] >= LONG_HOURS):
        hh = r["hourly"]
        if len(hh) < 2:
            continue
        first, last = hh[0], hh[-1]
        for key, what in (
            ("fmean_over_lower", "smallest mean force / lower limit"),
            ("f_over_extreme", "largest f / extreme limit"),
            ("gain_max", "largest tracked force ratio"),
        ):
            rep.rows.append(
                Row(
                    f"free.long{r['seed']}.{key}.last_hour",
                    last[key],
                    None,
                    "-",
                    f"{what} in hour {len(hh)} of a continuous run; hour 1: {first[key]:.3f}",
                )
            )


def _plot(results: list[dict[str, Any]], plot_dir: Path) -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axs = plt.subplots(1, 3, figsize=(13, 3.6))
    for ax, (kind, key, unit, target) in zip(
        axs,
        (
            (ProcessEventKind.BREAKAGE, "delay_revs", "rev", TARGET_BREAKAGE_REVS),
            (ProcessEventKind.COLLISION, "delay_from_estimate_s", "s", TARGET_COLLISION_S),
            (ProcessEventKind.MISSING_TOOL, "delay_blocks", "block", 1.0),
        ),
        strict=True,
    ):
        for size, c in (("clear", "tab:blue"), ("edge", "tab:orange")):
            d = [r[key] for r in results if r["kind"] == kind and r["size"] == size and key in r]
            if d:
                ax.hist(d, bins=30, alpha=0.6, color=c, label=f"{size} ({len(d)})")
        ax.axvline(target, color="k", ls="--", label="target")
        ax.set_xlabel(f"{kind} delay [{unit}]")
        ax.legend(fontsize=8)
    fig.tight_layout()
    plot_dir.mkdir(parents=True, exist_ok=True)
    path = plot_dir / "process_monitoring_delays.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return str(path)


def example_figure(plot_dir: Path) -> str:
    """One tooth breakage on the default program (seed 0): the estimated force with its
    taught envelope and extreme limit, the pattern change ``d`` with its threshold, the
    event's first sample and the alarm."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from machine.process import ProcessEvent, default_program

    rng = np.random.default_rng(0)
    noise = {"resolution": 5e-9, "current_noise": 0.01, "mass_error": 0.02}
    machine, obs, mon, state = _setup(default_program(), rng, noise, override_prob=0.0)
    _teach(machine, obs, mon, state)
    machine.events = [
        ProcessEvent(ProcessEventKind.BREAKAGE, machine.part, 40, 0.5, 0.3e-3, flute=1)
    ]
    for b in machine.program.blocks:
        (r,) = machine.run_block(b)
        _, m = _watch(obs, mon, state, r)
        if b.line == 40:
            break
    ts = machine.sample_time
    k_ev = r.events[0].sample - r.k0
    al = next(a for a in m.alarms if a.detector == ProcessEventKind.BREAKAGE)
    k_al = al.sample - (int(state["samples"][0]) - r.n)
    sl = slice(max(0, k_ev - 1500), min(r.n, k_ev + 1500))
    t = (np.arange(r.n)[sl] - k_ev) * ts * 1e3
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    a1.plot(t, m.f[sl], lw=0.6, color="0.6", label="|F| estimated from the drives")
    a1.plot(t, m.f_mean[sl], color="tab:blue", label="mean over a revolution")
    a1.fill_between(
        t,
        m.lower[sl],
        m.upper[sl],
        color="tab:blue",
        alpha=0.15,
        label="taught band (missing-tool limit below)",
    )
    a1.plot(t, m.extreme[sl], color="tab:red", ls="--", label="extreme limit (collision)")
    a1.set_ylabel("force [N]")
    a1.legend(fontsize=8, loc="upper left")
    a2.plot(t, m.pattern[sl], color="tab:purple", label="pattern change d")
    a2.plot(t, m.pattern_limit[sl], color="tab:purple", ls="--", label="breakage threshold")
    a2.fill_between(
        t,
        0,
        np.where(m.suspected[sl] > 0, m.pattern_limit[sl], 0),
        color="orange",
        alpha=0.3,
        label="suspected (canceller held)",
    )
    a2.set_ylabel("d [-]")
    a2.set_xlabel("time from the breakage's first sample [ms]")
    for ax in (a1, a2):
        ax.axvline(0.0, color="k", lw=1)
        ax.axvline((k_al - k_ev) * ts * 1e3, color="tab:red", lw=1)
    a2.legend(fontsize=8, loc="upper left")
    rev = 60.0 / r.spindle_rpm * 1e3
    a1.set_title(
        f"tooth breakage, line 40, {r.spindle_rpm:.0f} rpm: alarm after "
        f"{(k_al - k_ev) * ts * 1e3:.1f} ms ({(k_al - k_ev) * ts * 1e3 / rev:.2f} rev)"
    )
    fig.tight_layout()
    plot_dir.mkdir(parents=True, exist_ok=True)
    path = plot_dir / "process_monitoring_breakage.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return str(path)


def run(
    *, quick: bool = False, plot_dir: Path | None = None, progress: bool = True
) -> Reproduction:
    """The Monte Carlo (``quick``: a few seeds per kind and 3 event-free minutes).

    The full run keeps every finished case in :func:`cache_path` and resumes from it.
    """
    from server.experiments.reproductions import _centre_rows

    results = run_cases(_cases(quick), progress=progress, cache=None if quick else cache_path())
    rep = build(results)
    centre = run_centre(quick=quick, progress=progress)
    _centre_rows.centre_rows(rep, centre)
    if plot_dir is not None:
        rep.figures.append(_plot(results, plot_dir))
        rep.figures.append(example_figure(plot_dir))
        rep.figures.append(_centre_rows.plot(centre, plot_dir))
    return rep
