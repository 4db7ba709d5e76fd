"""Recorded machining-centre traces for the plant bench (issue 32 item 3).

A plant's feeders replay what was recorded, they do not simulate: :func:`record` runs a
machining centre (:mod:`machine.centre`, the program of plant machine ``index``,
:func:`machine.centre.program.program_variant`) once, exports its CNC's trace at
``rate_hz`` and writes it as a measured log (CSV and sidecar: the machine description of
:func:`machine.centre.signals.description_dict`, the program, the identity columns tool,
line and override), which ``cutwatch feed LOG --machine a,b,...`` then publishes for many
machines from one process. Events (breakage, collision, missing tool, one in a cut
block of each part with probability ``event_rate``) are injected only after the
monitors' teach-in (the first ``teach_parts`` parts are good); their truth goes to
``<stem>.events.json`` beside the log (never published), so that the bench can score the
events the workers raise (:func:`score`).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, TypedDict

import numpy as np

#: what a raised event may lag the truth's time and still count as found [s]: the
#: longest a detector waits (one block of the program) is far shorter; more means
#: another part's event
MATCH_S = 10.0
#: what a raised event may lead the truth's time [s] once on the machine's clock
#: (:func:`on_machine_clock`): a detector raises at or after the event's sample; this
#: allows the sample grid's rounding only
EARLY_S = 0.1


class TrueEvent(TypedDict):
    """An event the trace holds (its truth): kind, time on the log's clock [s], G-code
    line, tool, size."""

    kind: str
    t: float
    line: int
    tool: int
    size: float


class PlantTruth(TypedDict):
    """A recorded trace's truth (:func:`record`; ``<stem>.events.json``)."""

    events: list[TrueEvent]
    teach_parts: int
    seconds: float
    program: str
    rate_hz: float


class Score(TypedDict):
    """The monitors' events scored against the truth (:func:`score`)."""

    events_due: int
    found: int
    beside: int
    false: int
    detection: float


def record(
    path: Path,
    *,
    index: int = 0,
    seed: int = 0,
    seconds: float = 240.0,
    rate_hz: float = 500.0,
    event_rate: float = 0.5,
    teach_parts: int = 5,
) -> PlantTruth:
    """Write ``seconds`` of machine ``index``'s trace at ``rate_hz`` to ``path`` (CSV +
    sidecar) and its events' truth to ``<stem>.events.json``; returns that truth."""
    from common.event_kinds import ProcessEventKind
    from machine.centre import signals
    from machine.centre.program import program_variant
    from machine.centre.sim import MachiningCentre
    from machine.centre.trace import CncTrace, TraceParams
    from machine.process import EVENT_KINDS, ProcessEvent
    from server.pipeline.centre_feed import EVENT_SIZES
    from server.records.measured_log import write_log

    machine = MachiningCentre(program=program_variant(index))
    state = machine.initial_state(seed=seed)
    trace = CncTrace(TraceParams(rate_hz, "sample"), machine.sample_time)
    tstate = trace.initial_state()
    rng = np.random.default_rng([seed, 32])
    cuts = [b.line for b in machine.program.blocks if b.cut is not None]
    chunk = trace.factor * max(1, round(0.1 * rate_hz))  # 100 ms of trace
    parts: list[dict[str, Any]] = []
    events: list[TrueEvent] = []
    part = -1
    broken: set[int] = set()
    while state.k * machine.sample_time < seconds:
        if state.part != part:
            part = state.part
            for tool in sorted(broken):  # a tool lost in the last part is replaced
                state = machine.replace_tool(state, tool)
            broken.clear()
            if part >= teach_parts and rng.random() < event_rate:
                kind = str(rng.choice(EVENT_KINDS))
                ev = ProcessEvent(kind, part, int(rng.choice(cuts)), float(rng.uniform(0.2, 0.8)),
                                  EVENT_SIZES[kind], int(rng.integers(0, 8)))  # fmt: skip
                state = machine.schedule(state, ev)
        state, rec = machine.step(state, chunk)
        tstate, tr = trace.export(tstate, rec)
        if tr.n:
            parts.append(signals.columns(tr, machine.params))
        for e in tr.events:
            if e.kind in (ProcessEventKind.BREAKAGE, ProcessEventKind.MISSING_TOOL):
                broken.add(int(e.tool))
            events.append({"kind": str(e.kind), "t": float(e.t), "line": int(e.line),
                           "tool": int(e.tool), "size": float(e.size)})  # fmt: skip
    cols = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    side = {**signals.description_dict(machine.params, rate_hz), "program": machine.program.name}
    write_log(path, cols, side)
    truth: PlantTruth = {"events": events, "teach_parts": teach_parts,
                         "seconds": float(cols["t"][-1]), "program": machine.program.name,
                         "rate_hz": rate_hz}  # fmt: skip
    Path(path).with_suffix(".events.json").write_text(json.dumps(truth, indent=1))
    return truth


def on_machine_clock(
    raised: dict[str, list[dict[str, Any]]], origins: dict[str, float | None]
) -> dict[str, list[dict[str, Any]]]:
    """Each machine's events with their ``t`` on the machine's own clock (the log's):
    a broker source's time counts from the first sample its worker received, so the
    worker's events are early by the time the feed had run when it joined; ``origins``
    is that time per machine (the worker's ``feed_origin_s``; None: not known, left)."""
    out: dict[str, list[dict[str, Any]]] = {}
    for m, evs in raised.items():
        o = origins.get(m)
        out[m] = [{**e, "t": float(e["t"]) + (o or 0.0)} for e in evs]
    return out


def score(truth: list[TrueEvent], raised: dict[str, list[dict[str, Any]]], t_end: float) -> Score:
    """Per machine, each true event that the feed reached (``t < t_end``, the log's time
    the window covered) is found when the machine raised an event of its kind on its
    G-code line from :data:`EARLY_S` before it to :data:`MATCH_S` after it. Every other
    raised event is ``beside`` a true event when it is on that event's line in that
    window (another monitor's, or another detector's, alarm of the same event: a tool
    lost also reads as a breakage), else ``false``. ``raised``: per machine, its events
    as ``{"kind", "t", "line"}`` on the machine's clock (:func:`on_machine_clock`)."""

    def near(r: dict[str, Any], e: TrueEvent) -> bool:
        return bool(r.get("line") == e["line"] and e["t"] - EARLY_S <= r["t"] <= e["t"] + MATCH_S)

    due = [e for e in truth if e["t"] < t_end - MATCH_S]
    found = beside = false = 0
    for evs in raised.values():
        used: set[int] = set()
        for e in due:
            hits = (i for i, r in enumerate(evs) if i not in used and r["kind"] == e["kind"])
            hit = next((i for i in hits if near(evs[i], e)), None)
            if hit is not None:
                used.add(hit)
                found += 1
        for i, r in enumerate(evs):
            if i not in used:
                if any(near(r, e) for e in truth):
                    beside += 1
                else:
                    false += 1
    n = len(due) * len(raised)
    return {"events_due": n, "found": found, "beside": beside, "false": false,
            "detection": found / n if n else float("nan")}  # fmt: skip


__all__ = ["EARLY_S", "MATCH_S", "on_machine_clock", "record", "score"]
