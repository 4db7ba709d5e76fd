"""The detectors' confirmations before and after issue 32's physical rule, paired.

One simulation per seed (the machining-centre cases of ``reproduce process-monitoring``:
the same programs, events and event-free hours), every trace rate watched by **two**
copies of each monitor: ``before`` (the confirmations in samples of the rate: breakage
3 samples, collision 2, missing tool one revolution) and ``after`` (the defaults of
:class:`~estimators.monitoring.process.MonitorParams`: a share of a revolution, a time,
a time). The same cut, noise and event reach both, so every difference is the rule's.

``python -m server.experiments.confirmation_pairs --out FILE`` appends one JSON line per
case (resumes from FILE: a row stands for a case of the same kind, seed and hours) until
``--until`` (UTC ``HH:MM``, the next such time: tomorrow's if today's has passed) or the
cases are done;
``--summary FILE`` prints the paired tables. ``--quick`` runs two short cases (the
test's size).
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import math
import multiprocessing
import sys
from pathlib import Path
from typing import Any

import numpy as np

from common.event_kinds import ProcessEventKind
from server.experiments.confidence import rate_upper
from server.experiments.reproductions._centre_monitoring import (
    MONITORS,
    RATES,
    SETS,
    TEACH_PARTS,
    CentreCase,
    Watch,
    _run_parts,
    _score,
    event_program,
    free_program,
)
from server.experiments.reproductions._centre_rows import entry

VARIANTS = ("before", "after")
#: the settings of ``before`` (the rule in samples: the floors alone)
BEFORE: dict[str, float] = {"breakage_rev": 0.0, "collision_s": 0.0, "missing_s": 0.0}


class PairWatch(Watch):
    """A :class:`Watch` with a second monitor per signal set on the ``before`` rule."""

    def __init__(self, machine: Any, rate: float) -> None:
        from estimators.monitoring.process import MonitorParams, ProcessMonitor

        super().__init__(machine, rate)
        mp = MonitorParams(
            sample_time=self.ts, teach_parts=TEACH_PARTS, breakage_rev=BEFORE["breakage_rev"],
            collision_s=BEFORE["collision_s"], missing_s=BEFORE["missing_s"],
        )  # fmt: skip
        self.mon_b = {s: ProcessMonitor(mp) for s in MONITORS}
        self.mstate_b = {s: self.mon_b[s].initial_state() for s in MONITORS}
        self.alarms_b: list[dict[str, Any]] = []

    def _step(
        self, s: str, xyp: tuple[Any, Any, Any], kw: dict[str, Any], k0: int, key: tuple[int, int]
    ) -> None:
        """The block through both rules' monitors: ``after`` as :class:`Watch` does,
        ``before`` beside it with the same signals and identities."""
        super()._step(s, xyp, kw, k0, key)
        mb = self.mon_b[s].step(self.mstate_b[s], *xyp, **kw)
        for al in mb.alarms:
            self.alarms_b.append(
                {"set": s, "detector": str(al.detector), "k": int(al.sample),
                 "part": key[0], "line": key[1]}
            )  # fmt: skip


def _both_scores(w: PairWatch, kind: str, line: int, rpm: float) -> dict[str, Any]:
    after = _score(w, kind, line, rpm)
    keep = w.alarms
    w.alarms = w.alarms_b
    before = _score(w, kind, line, rpm)
    w.alarms = keep
    return {"after": after, "before": before}


def run_event(case: CentreCase) -> dict[str, Any]:
    """As the reproduction's :func:`run_event`, watched on both rules."""
    from machine.centre.sim import MachiningCentre
    from machine.process import ProcessEvent
    from server.experiments.reproductions._centre_monitoring import SIZES, _code

    rng = np.random.default_rng([32, _code(case.kind), case.seed])
    program, cut_lines = event_program(rng)
    line = int(rng.choice(cut_lines))
    tool = program.tools[0]
    size = float(rng.uniform(*SIZES[case.kind]))
    frac = float(rng.uniform(0.2, 0.8))
    if case.kind == ProcessEventKind.MISSING_TOOL and rng.random() < 0.5:
        frac = 0.0
    ev = ProcessEvent(case.kind, TEACH_PARTS, line, frac, size, int(rng.integers(tool.n_flutes)))
    machine = MachiningCentre(program=program, events=[ev], override_prob=0.0)
    state = machine.initial_state(int(rng.integers(2**31)))
    watches = [PairWatch(machine, r) for r in RATES]
    state = _run_parts(machine, state, watches, TEACH_PARTS)
    machine.override_prob = 0.3
    rpm = next(b.rpm for b in program.blocks if b.kind == "spindle")
    for w in watches:
        w.watch_from = w.n
    _run_parts(machine, state, watches, 1)
    res: dict[str, Any] = {**case_fields(case), "rpm": rpm}
    for w in watches:
        res[f"{w.rate:g}"] = _both_scores(w, case.kind, line, rpm)
    return res


def run_free(case: CentreCase) -> dict[str, Any]:
    """Event-free ``hours`` after the teach-in, on both rules: every alarm is false."""
    from machine.centre.sim import MachiningCentre
    from server.experiments.reproductions._centre_monitoring import _code

    rng = np.random.default_rng([32, _code("none"), case.seed])
    program = free_program(rng)
    machine = MachiningCentre(program=program, override_prob=0.0)
    state = machine.initial_state(int(rng.integers(2**31)))
    watches = [PairWatch(machine, r) for r in RATES]
    state = _run_parts(machine, state, watches, TEACH_PARTS)
    machine.override_prob = 0.2
    start = [(len(w.alarms), len(w.alarms_b)) for w in watches]
    t0 = state.k * machine.sample_time
    while state.k * machine.sample_time - t0 < case.hours * 3600.0:
        state = _run_parts(machine, state, watches, 1)
    res: dict[str, Any] = {
        **case_fields(case),
        "watched_h": (state.k * machine.sample_time - t0) / 3600.0,
    }  # fmt: skip
    for w, (a0, b0) in zip(watches, start, strict=True):
        res[f"{w.rate:g}"] = {"after": w.alarms[a0:], "before": w.alarms_b[b0:]}
    return res


def case_fields(case: CentreCase) -> dict[str, Any]:
    """What identifies and sizes a case, written into its row: the resume key."""
    return {
        "kind": case.kind, "seed": case.seed, "hours": case.hours,
        "machine": case.machine, "size": case.size,
    }  # fmt: skip


def _key(fields: dict[str, Any]) -> tuple[Any, ...]:
    return tuple(fields.get(k) for k in ("kind", "seed", "hours", "machine", "size"))


def remaining(todo: list[CentreCase], rows: list[dict[str, Any]]) -> list[CentreCase]:
    """The cases of ``todo`` not yet in ``rows``: a row counts for a case only if it was
    the same case in every field that sizes it (a ``--quick`` file reused as ``--out``
    of a full run does not stand for the full run's longer event-free cases; rows
    written before the hours were recorded match nothing and are run again)."""
    done = {_key(r) for r in rows}
    return [c for c in todo if _key(case_fields(c)) not in done]


def stop_time(until: str, now: dt.datetime) -> dt.datetime:
    """The next ``until`` (UTC ``HH:MM``) after ``now``: today's, or tomorrow's when
    today's is not later than ``now`` (``--until 06:00`` started at 22:00 runs the
    night, it does not stop after the first case)."""
    try:
        hh, mm = (int(x) for x in until.split(":"))
        if not (0 <= hh < 24 and 0 <= mm < 60):
            raise ValueError
    except ValueError:
        raise ValueError(f"--until: expected a UTC time HH:MM, found {until!r}") from None
    stop = now.replace(hour=hh, minute=mm, second=0, microsecond=0)
    return stop if stop > now else stop + dt.timedelta(days=1)


def _run(case: CentreCase) -> dict[str, Any]:
    return run_free(case) if case.kind == "none" else run_event(case)


def cases(n_free: int, hours: float, n_events: int, seed0: int) -> list[CentreCase]:
    """Interleaved: an event-free case, then one event of each kind, and so on."""
    out: list[CentreCase] = []
    kinds = list(ProcessEventKind)
    for i in range(max(n_free, n_events)):
        if i < n_free:
            out.append(CentreCase("none", seed0 + i, hours))
        if i < n_events:
            out += [CentreCase(str(k), seed0 + i) for k in kinds]
    return out


def _sets(sig: str) -> tuple[str, ...]:
    return MONITORS if sig == "both" else (sig,)


def summary(rows: list[dict[str, Any]]) -> str:
    """The paired tables: false alarms (before -> after, the after's one-sided 95 % upper
    bound per hour), and per event kind and signal set the events found (before -> after,
    the discordant pairs: lost by the new rule, won by it), the delay's change on the
    events both found and the p95 delay in the target's unit (before -> after)."""
    free = [r for r in rows if r["kind"] == "none"]
    ev = [r for r in rows if r["kind"] != "none"]
    hours = sum(r["watched_h"] for r in free)
    out = [
        f"event-free: {len(free)} cases, {hours:.2f} h at each rate (none in them: upper "
        f"bound {rate_upper(0, hours):.3f} per hour); events: {len(ev)}",
        "",
        "| signals | detector | " + " | ".join(f"{r:g} Hz" for r in RATES) + " |",
        "|---|---|" + "---|" * len(RATES),
    ]
    for sig in SETS:
        for det in [*ProcessEventKind, "machine"]:
            cells = []
            for rate in RATES:
                k = [
                    sum(1 for r in free for a in r[f"{rate:g}"][var]
                        if a["set"] in _sets(sig) and det in ("machine", a["detector"]))
                    for var in VARIANTS
                ]  # fmt: skip
                cells.append(f"{k[0]} -> {k[1]} (<= {rate_upper(k[1], hours):.2f}/h)")
            out.append(f"| {sig} | {det} | " + " | ".join(cells) + " |")
    out += ["", "| event | signals | " + " | ".join(f"{r:g} Hz" for r in RATES) + " |"]
    out.append("|---|---|" + "---|" * len(RATES))
    for kind in ProcessEventKind:
        rs = [r for r in ev if r["kind"] == kind]
        for sig in SETS if rs else ():
            cells = [_event_cell(kind, sig, rate, rs) for rate in RATES]
            out.append(f"| {kind} | {sig} | " + " | ".join(cells) + " |")
    return "\n".join(out)


def _event_cell(kind: str, sig: str, rate: float, rs: list[dict[str, Any]]) -> str:
    got = {v: [entry({f"{rate:g}": r[f"{rate:g}"][v]}, rate, sig) for r in rs] for v in VARIANTS}
    pairs = list(zip(got["before"], got["after"], strict=True))
    kb = sum(1 for b, _ in pairs if b["detected"])
    ka = sum(1 for _, a in pairs if a["detected"])
    lost = sum(1 for b, a in pairs if b["detected"] and not a["detected"])
    won = sum(1 for b, a in pairs if a["detected"] and not b["detected"])
    both = [(b, a) for b, a in pairs if b["detected"] and a["detected"]]
    cell = f"{kb} -> {ka}/{len(rs)}, lost {lost}, won {won}"
    if both:
        ms = [1e3 * (a["delay_s"] - b["delay_s"]) for b, a in both]
        cell += f"; later by {np.median(ms):.1f} ms median, {max(ms):.0f} ms max"
    return cell + _p95(kind, got)


#: each kind's delay in its target's unit (as the reproduction's rows)
_TARGET_KEY = {
    ProcessEventKind.BREAKAGE: ("delay_revs", 1.0, "rev"),
    ProcessEventKind.COLLISION: ("delay_from_estimate_s", 1e3, "ms"),
    ProcessEventKind.MISSING_TOOL: ("delay_blocks", 1.0, "block"),
}


def _p95(kind: str, got: dict[str, list[dict[str, Any]]]) -> str:
    """The p95 delay in the target's unit, before -> after (each over its own hits)."""
    key, scale, unit = _TARGET_KEY[ProcessEventKind(kind)]
    p = []
    for v in VARIANTS:
        d = [scale * g[key] for g in got[v] if g["detected"] and key in g]
        d = [x for x in d if math.isfinite(x)]
        p.append(f"{np.percentile(d, 95):.3g}" if d else "-")
    return f"; p95 {p[0]} -> {p[1]} {unit}"


def _load(path: Path) -> list[dict[str, Any]]:
    rows = []
    if path.is_file():
        for line in path.read_text().splitlines():
            try:
                rows.append(json.loads(line))
            except ValueError:
                continue
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, help="JSON-lines file the cases go to (resumed)")
    ap.add_argument("--summary", type=Path, help="print the paired tables of this file")
    ap.add_argument("--free", type=int, default=40, help="event-free cases (default 40)")
    ap.add_argument("--hours", type=float, default=0.5, help="hours per event-free case")
    ap.add_argument("--events", type=int, default=30, help="events per kind (default 30)")
    ap.add_argument("--seed0", type=int, default=1000, help="first seed (default 1000)")
    ap.add_argument("--until", help="stop starting cases after this UTC time, HH:MM")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--quick", action="store_true", help="one short event-free case and "
                    "one event of each kind")  # fmt: skip
    a = ap.parse_args(argv)
    if a.summary:
        print(summary(_load(a.summary)))
        return 0
    if a.out is None:
        ap.error("--out FILE or --summary FILE")
    todo = cases(1, 0.01, 1, a.seed0) if a.quick else cases(a.free, a.hours, a.events, a.seed0)
    todo = remaining(todo, _load(a.out))
    stop = None
    if a.until:
        try:
            stop = stop_time(a.until, dt.datetime.now(dt.UTC))
        except ValueError as e:
            ap.error(str(e))
    from tqdm import tqdm

    with multiprocessing.get_context("spawn").Pool(a.workers) as pool, a.out.open("a") as f:
        for r in tqdm(
            pool.imap_unordered(_run, todo, chunksize=1), total=len(todo), file=sys.stderr
        ):
            f.write(json.dumps(r) + "\n")
            f.flush()
            if stop is not None and dt.datetime.now(dt.UTC) >= stop:
                pool.terminate()
                break
    print(summary(_load(a.out)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
