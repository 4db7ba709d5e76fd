"""One machine's runtime: its pipeline, with its events, estimates, checkpoints and tool lives.

:class:`MachineRuntime` is what ``cutwatch serve`` and ``cutwatch worker`` share. The
service wraps one with pacing and the browser frames
(:class:`server.service.loop.LiveLoop`); a plant's worker holds many, one per machine
(:class:`server.pipeline.worker.Worker`). Whatever the host, a machine's messages are
built here, in one place:

- :meth:`MachineRuntime.step` advances the pipeline and takes its events (stamped with
  the machine's name and a stable id, :func:`~server.records.monitor_events.event_id`)
  and the tools it changed;
- :meth:`MachineRuntime.emit` hands the events on at once: to the broker first
  (:class:`~server.pipeline.events_out.EventsPublisher`: the feed-hold command before its
  event), then to the listeners (the service's browser hub), to the kept list and to the
  history;
- :meth:`MachineRuntime.estimates` feeds the estimates publisher every block and
  publishes when due (:class:`~server.pipeline.estimates_out.EstimatesPublisher`), with the
  runtime's health and the monitor's status;
- :meth:`MachineRuntime.resume` and :meth:`MachineRuntime.save` read and write the
  pipeline's checkpoint (a writer thread, :class:`CheckpointWriter`, keeps the file
  system's waits off the loop); a file of another version is refused with its version
  named and the runtime starts fresh;
- the tools changed go to the history (:meth:`MachineRuntime.keep_tool_lives`);
- the latest :data:`EVENTS_KEPT` events with their acknowledgements, for the snapshot,
  the status strip (``unacked``: the same in the estimates of either host) and a new
  browser's backlog (:meth:`MachineRuntime.listen`).

What a host adds: the service paces the source and builds the browser frames (its hub
listens to the events); a worker steps its machines in turn.

Thread safety: :attr:`MachineRuntime.lock` serialises the pipeline (a host's routes
take it; a worker's single loop thread takes it uncontended); the kept events have
their own lock.
"""

from __future__ import annotations

import collections
import dataclasses
import logging
import math
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, Protocol, TypedDict, TypeVar

import numpy as np

from common.errors import ParameterError
from common.jsonsafe import json_safe
from common.state_io import StateFormatError
from server.pipeline.checkpoint import PipelineState, load_checkpoint, save_checkpoint
from server.pipeline.estimates_out import EstimatesPublisher, RuntimeHealth, StatusStrip
from server.pipeline.events_out import EventsPublisher
from server.pipeline.live_pipeline import LivePipeline
from server.records.history.store import ToolChange
from server.records.monitor_events import KINDS, EventRecord, MonitorEvent, event_id, event_record

log = logging.getLogger("uvicorn.error")

#: events kept in memory for the snapshot (the history keeps all of them)
EVENTS_KEPT = 200
#: unacknowledged events tracked for the status (the oldest forgotten beyond)
UNACKED_KEPT = 10_000

__all__ = [
    "EVENTS_KEPT",
    "UNACKED_KEPT",
    "CheckpointStatus",
    "CheckpointWriter",
    "EventHistory",
    "MachineRuntime",
]

_T = TypeVar("_T")


class CheckpointStatus(TypedDict, total=False):
    """Where a runtime's checkpoint was read from or refused, and when written
    (:attr:`MachineRuntime.checkpoint_status`; ``path`` and ``resumed`` always there)."""

    path: str | None
    resumed: bool
    resumed_t: float
    refused: str
    kept_aside: str
    saved_t: float
    saved_wall: float
    error: str


class EventHistory(Protocol):
    """What a runtime asks of the event history (:class:`server.records.history.HistoryStore`)."""

    def add_events(self, events: list[MonitorEvent]) -> None: ...

    def acknowledge(self, event_id: str, by: str) -> EventRecord | None: ...

    def add_tool_changes(self, changes: list[ToolChange]) -> Any: ...

    def recent(self, n: int) -> Sequence[EventRecord]: ...


class CheckpointWriter:
    """One thread that writes the checkpoints runtimes hand over (:meth:`put`); the newest
    state of a file wins over one not yet written. :meth:`stop` writes what is left."""

    def __init__(self, name: str = "cutwatch-checkpoints") -> None:
        self.name = name
        self._pending: dict[Path, tuple[MachineRuntime, PipelineState]] = {}
        self._lock = threading.Lock()
        self._ready = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name=self.name, daemon=True)
        self._thread.start()

    def put(self, runtime: MachineRuntime, path: Path, state: PipelineState) -> None:
        """Hand a state over (never waits for the disk)."""
        with self._lock:
            self._pending[path] = (runtime, state)
        self._ready.set()

    def busy(self, path: Path) -> bool:
        """A state of ``path`` is waiting to be written."""
        with self._lock:
            return path in self._pending

    def stop(self, timeout: float = 10.0) -> None:
        """Stop the thread, then write what is still waiting."""
        self._stop.set()
        self._ready.set()
        if self._thread is not None:
            self._thread.join(timeout)
        self._drain()

    def _run(self) -> None:
        while not self._stop.is_set():
            self._ready.wait(0.5)
            self._ready.clear()
            self._drain()

    def _drain(self) -> None:
        while True:
            with self._lock:
                if not self._pending:
                    return
                path = next(iter(self._pending))
                runtime, state = self._pending.pop(path)
            runtime.write(path, state)


class MachineRuntime:
    """One machine's pipeline and everything it hands out (see the module docstring).

    Parameters
    ----------
    machine
        The machine's name: stamped on every event, the key of its broker topics.
    pipeline
        The pipeline to run; :meth:`set_pipeline` replaces it.
    events_out, estimates_out
        The broker's publishers (None: nothing published).
    history
        Where events and tool lives are kept (None: memory only).
    checkpoint
        The pipeline's checkpoint file (None: none read or written).
    writer
        The thread that writes checkpoints handed over without waiting (None: written
        in the caller's thread).
    host
        Who runs it: ``"serve"`` or ``"worker <name>"`` (in the estimates' health).
    lock
        The lock serialising the pipeline (default: a new one).
    """

    def __init__(
        self,
        machine: str,
        pipeline: LivePipeline,
        *,
        events_out: EventsPublisher | None = None,
        estimates_out: EstimatesPublisher | None = None,
        history: EventHistory | None = None,
        checkpoint: Path | None = None,
        writer: CheckpointWriter | None = None,
        host: str = "serve",
        lock: threading.RLock | None = None,
    ) -> None:
        self.machine = machine
        self.pipeline = pipeline
        self.events_out = events_out
        self.estimates_out = estimates_out
        self.history = history
        self.checkpoint = checkpoint
        self.writer = writer
        self.host = host
        self.lock = lock or threading.RLock()
        #: where the pipeline's checkpoint was read from or refused, and when written
        self.checkpoint_status: CheckpointStatus = {
            "path": str(checkpoint) if checkpoint is not None else None,
            "resumed": False,
        }
        self._home = (pipeline.scenario, pipeline.source.name)
        self.blocks = 0
        self.history_errors = 0
        self._lives: list[ToolChange] = []  # tool lives not yet in the history
        #: called with each event's record (:meth:`MonitorEvent.record`) when it is raised
        #: or acknowledged, under the events' lock (the service's browser hub)
        self.listeners: list[Callable[[EventRecord], None]] = []
        #: events raised since the start, by kind
        self.events_total: dict[str, int] = dict.fromkeys(KINDS, 0)
        self._ev_lock = threading.Lock()  # the kept events, their counts, listeners
        self._events: collections.deque[EventRecord] = collections.deque(maxlen=EVENTS_KEPT)
        self._unacked: dict[str, str] = {}  # id -> action, oldest first
        self._step_s: collections.deque[float] = collections.deque(maxlen=200)
        self._step_p50_ms = math.nan

    # ------------------------------------------------------------------ the pipeline
    def set_pipeline(self, pipe: LivePipeline) -> None:
        """Run ``pipe`` from now on; the installed observer effects carry over."""
        with self.lock:
            if self.pipeline.effects:
                pipe.set_observer_effects(self.pipeline.effects)
            self.pipeline = pipe

    @property
    def is_home(self) -> bool:
        """The pipeline running is the one the runtime started with (its scenario and
        source): only its state is checkpointed."""
        p = self.pipeline
        return (p.scenario, p.source.name) == self._home

    def step(self, n: int) -> tuple[dict[str, np.ndarray], list[MonitorEvent]]:
        """Advance ``n`` samples (fewer, or none, from a live feed); the channels and the
        events raised, stamped with the machine's name and id. Tool lives are kept for
        :meth:`keep_tool_lives`."""
        w0 = time.perf_counter()
        with self.lock:
            out = self.pipeline.step(n)
            events = [self.stamp(e) for e in self.pipeline.take_events()]
            if len(out["t"]):
                self.blocks += 1
                self._lives += self.pipeline.take_tool_changes()
                self._step_s.append(time.perf_counter() - w0)
                if self.blocks % 20 == 0:  # for the estimates' health, not per message
                    self._step_p50_ms = 1e3 * float(np.median(self._step_s))
        return out, events

    def stamp(self, ev: MonitorEvent) -> MonitorEvent:
        """The event with this machine's name and its stable id."""
        machine = ev.machine or self.machine
        return dataclasses.replace(ev, machine=machine, id=event_id(ev, machine))

    # ------------------------------------------------------------------ events
    def emit(self, events: list[MonitorEvent]) -> None:
        """Hand the events of a block on, at once: to the broker (the command's latency
        first), to the listeners, to the history."""
        if not events:
            return
        if self.events_out is not None:
            self.events_out.publish(events)
        with self._ev_lock:  # a listener added meanwhile gets each event once
            for e in events:
                rec = e.record()
                self._events.append(rec)
                self.events_total[e.kind] = self.events_total.get(e.kind, 0) + 1
                self._unacked[e.id] = e.action
                while len(self._unacked) > UNACKED_KEPT:
                    del self._unacked[next(iter(self._unacked))]
                for fn in self.listeners:
                    fn(rec)
        if self.history is not None:
            try:
                self.history.add_events(events)
            except Exception as exc:  # the loop goes on; the log and /metrics say so
                self.history_errors += 1
                log.warning("cutwatch: %d event(s) not kept in the history: %s", len(events), exc)

    def reload_events(self) -> None:
        """The latest kept events from the history (after a restart): in the snapshot
        again, sent to a new client and counted in the status while not acknowledged
        (not counted in :attr:`events_total`, which counts since this start, nor
        published again)."""
        if self.history is None:
            return
        try:
            recs = self.history.recent(EVENTS_KEPT)
        except Exception as exc:  # the runtime starts without them; the log says why
            log.warning("cutwatch: the kept events were not reloaded: %s", exc)
            return
        with self._ev_lock:
            for r in recs:
                rec = event_record(r)
                self._events.append(rec)
                if not rec["acked"]:
                    self._unacked[str(rec["id"])] = str(rec["action"])

    def announce(self, rec: EventRecord) -> None:
        """An event changed (acknowledged): its new record replaces the kept copy and goes
        to every listener; the status counts it as acknowledged."""
        rec = event_record(rec)
        with self._ev_lock:
            for i, old in enumerate(self._events):
                if old["id"] == rec["id"]:
                    self._events[i] = rec
            if rec["acked"]:
                self._unacked.pop(str(rec["id"]), None)
            for fn in self.listeners:
                fn(rec)

    def listen(self, register: Callable[[], _T]) -> tuple[_T, list[EventRecord]]:
        """Call ``register()`` (a new client's, adding it to the listeners' audience)
        under the events' lock; what it returned and the kept events not yet
        acknowledged (oldest first): an event raised meanwhile is in one of the two,
        never in both."""
        with self._ev_lock:
            got = register()
            backlog = [r.copy() for r in self._events if not r["acked"]]
        return got, backlog

    def recent_events(self) -> list[EventRecord]:
        """The kept events (at most :data:`EVENTS_KEPT`), newest first."""
        with self._ev_lock:
            return [r.copy() for r in reversed(self._events)]

    def unacked(self) -> tuple[int, bool]:
        """Events not yet acknowledged, and whether one of them is an alarm or a feed hold."""
        with self._ev_lock:
            return len(self._unacked), any(a != "notice" for a in self._unacked.values())

    def keep_tool_lives(self) -> None:
        """Write the tools changed to the history (committed before the loop goes on; a
        failed write is kept and tried again after the next block)."""
        if not self._lives:
            return
        if self.history is None:
            self._lives.clear()
            return
        try:
            self.history.add_tool_changes(self._lives)
        except Exception as exc:  # a full disk must not stop the loop; say so, retry
            log.warning("cutwatch: tool lives not kept yet (retried): %s", exc)
            return
        self._lives.clear()

    def monitor_status(self) -> StatusStrip:
        """The status strip's fields (``server.service.messages.MonitorStatus``): the
        pipeline's, with the events waiting for an acknowledgement (``unacked``) and
        state ``alarm`` while an alarm or a feed hold is among them (whatever the
        monitor's own state). JSON-safe."""
        with self.lock:
            st = dict(self.pipeline.monitor_status())
        n, alarm = self.unacked()
        st["unacked"] = n
        if alarm:
            st["state"] = "alarm"
        return json_safe(st)

    # ------------------------------------------------------------------ estimates
    def estimates(
        self,
        out: Mapping[str, np.ndarray],
        now: float,
        feed_health: Mapping[str, Any] | None = None,
    ) -> bool:
        """Feed the block to the estimates publisher and publish when due (on the wall
        clock for a paced source, on the machine's time for a live feed); True when a
        message went out."""
        pub = self.estimates_out
        if pub is None:
            return False
        pub.observe(out)
        with self.lock:
            p = self.pipeline
            src = p.source
            if not pub.due(now, p.t, paced=src.paced):
                return False
            body = pub.build(
                now,
                p.channels(),
                p.t,
                src.name,
                health=self.health(),
                drive_wall=getattr(src, "last_wall", None),
                feed_health=feed_health,
                monitor=self.monitor_status(),
            )
            t = p.t
        return pub.publish(body, now, t)

    def health(self) -> RuntimeHealth:
        """The runtime's own health (the estimates message's): who runs it (``serve``, a
        worker), the blocks stepped, whether it resumed from a checkpoint, and the p50 of
        a block's wall time over the last 200 blocks [ms]."""
        return {
            "runtime": self.host,
            "blocks": self.blocks,
            "resumed": bool(self.checkpoint_status.get("resumed")),
            "step_ms_p50": self._step_p50_ms,
        }

    # ------------------------------------------------------------------ checkpoints
    def resume(self) -> bool:
        """Continue from the checkpoint file, if there is one of this pipeline's scenario
        and source; else start fresh and say why (:attr:`checkpoint_status`, the log).
        True when resumed."""
        path = self.checkpoint
        if path is None or not path.exists():
            return False
        state = None
        try:
            state = load_checkpoint(path)
            with self.lock:
                self.pipeline.restore(state)
        except (StateFormatError, ParameterError, OSError) as exc:
            self.checkpoint_status["resumed"] = False
            self.checkpoint_status["refused"] = str(exc)
            log.warning("cutwatch: %s: checkpoint refused, starting fresh: %s", self.machine, exc)
            if state is not None and isinstance(exc, ParameterError):
                self._keep_aside(path, state)
            return False
        self.checkpoint_status["resumed"] = True
        self.checkpoint_status["resumed_t"] = state.t
        log.warning("cutwatch: %s resumed from %s at t = %.3f s", self.machine, path, state.t)
        return True

    def _keep_aside(self, path: Path, state: PipelineState) -> None:
        """A readable state of another pipeline (another scenario or source: the stage's
        ``default`` after the machining centre became the default, issue 31) is moved
        beside the checkpoint, ``<stem>.<scenario>-<source>.t<seconds>.npz``, not
        overwritten by this pipeline's first save; renamed back to the checkpoint's name
        it resumes under its own scenario."""
        aside = path.with_name(
            f"{path.stem}.{state.scenario}-{state.source}.t{int(state.t)}{path.suffix}"
        )
        try:
            path.replace(aside)
        except OSError as exc:
            log.warning("cutwatch: %s: could not keep %s aside: %s", self.machine, path, exc)
            return
        self.checkpoint_status["kept_aside"] = str(aside)
        log.warning(
            "cutwatch: %s: the state of scenario %r (%s source) kept as %s",
            self.machine,
            state.scenario,
            state.source,
            aside,
        )

    def save(self, *, wait: bool = True) -> bool:
        """Take the pipeline's state (when it is the one the runtime started with: not a
        replay or another scenario) and write it: now (``wait``) or by the
        :attr:`writer` (the newest state wins). True when a state was taken."""
        path = self.checkpoint
        if path is None:
            return False
        with self.lock:
            if not self.is_home:
                return False
            state = self.pipeline.state()
        if wait or self.writer is None:
            self.write(path, state)
        else:
            self.writer.put(self, path, state)
        return True

    def write(self, path: Path, state: PipelineState) -> None:
        """Write ``state`` to ``path`` (atomically); a failure is said, never raised."""
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            save_checkpoint(path, state)
        except OSError as exc:  # a full disk must not stop the loop; say so
            self.checkpoint_status["error"] = f"{type(exc).__name__}: {exc}"
            log.warning("cutwatch: %s: checkpoint not written: %s", self.machine, exc)
            return
        self.checkpoint_status["saved_t"] = state.t
        self.checkpoint_status["saved_wall"] = time.time()
