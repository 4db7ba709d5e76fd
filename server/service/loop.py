"""The live service's loop: one machine's runtime, paced, and its frames for the browsers.

:class:`LiveLoop` wraps one :class:`~server.pipeline.runtime.MachineRuntime` (the
pipeline with its events, estimates, checkpoints and tool lives: what a plant's worker
runs too) with pacing and the browser frames. It owns simulated time: it steps the
pipeline in whole blocks (``block_ms``) on a schedule anchored to the wall clock,
``due(T) = wall0 + (T - sim0) / speed``; a block whose end lies at simulated time ``T``
is computed at ``due(T)``. Samples are never skipped or duplicated: after a host stall
the loop runs blocks back to back until it has caught up, and reports the lag (how late
a block finished against its due time). A lag beyond ``max_lag_s`` re-anchors the clock
(counted in ``stalls``) rather than racing forever.

Frames for the WebSocket clients are built at ``frame_hz`` from the blocks since the last
frame, decimated for display, encoded once and handed to :class:`Hub`, which keeps a
bounded latest-value-wins queue per client (:mod:`server.service.hub`). The loop never
waits for a client.

The monitor's events (:mod:`server.records.monitor_events`) are taken from the pipeline
after every block and handed on by the runtime at once, not at the next frame: to the
broker first (the feed-hold command and the event), then to every client as an ``event``
message (never dropped, unlike frames: the hub listens to the runtime), then to the
history (``LiveLoop.history``). The runtime keeps the latest events (with their
acknowledgements) for ``/api/snapshot``, counts them for ``/metrics``, and a new client
gets the unacknowledged ones right after its ``hello``; every frame carries the
monitor's status (``Data.status``).
"""

from __future__ import annotations

import collections
import logging
import math
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypedDict, cast

import numpy as np

from common.errors import ParameterError
from harness.accuracy import AccuracySummary
from server.errors import CutwatchError
from server.pipeline.broker import BrokerConfig, parse_broker_url
from server.pipeline.centre_wear_part import WearLabel
from server.pipeline.drive_feed import DriveFeed
from server.pipeline.estimates_out import EstimatesPublisher
from server.pipeline.events_out import EventsPublisher
from server.pipeline.knobs import Knob, KnobValue
from server.pipeline.live_pipeline import LivePipeline, MachineInfo
from server.pipeline.mqtt_source import MqttSource
from server.pipeline.opcua_source import OpcuaSource
from server.pipeline.part import PartInfo
from server.pipeline.process_part import Relearned
from server.pipeline.runtime import (
    CheckpointStatus,
    CheckpointWriter,
    EventHistory,
    MachineRuntime,
)
from server.pipeline.sources import Scheduled
from server.records.history import HistoryStore
from server.records.monitor_events import EventRecord
from server.service import protocol
from server.service.frame_slots import FrameSlots
from server.service.hub import ClientQueue, Hub
from server.service.messages import Event, LoopHealth, MonitorStatus
from server.service.settings import MAX_SPEED, Settings

if TYPE_CHECKING:
    from estimators.observer_effects import ObserverEffect
    from server.service.recording import Recording, RecordingSidecar
    from server.service.viser_scene import StageScene


#: significant digits of the displayed samples (relative to each frame's largest value)
DISPLAY_DIGITS = 5


#: how often the loop looks for new samples of a live feed (its latency floor) [s]
LIVE_POLL_S = 0.01

#: the service's log (uvicorn prints its warnings)
log = logging.getLogger("uvicorn.error")

#: injected events whose truth /api/snapshot shows (the latest)
INJECTED_KEPT = 50


def checkpoint_path(settings: Settings) -> Path | None:
    """Where the service keeps its pipeline's state (None: ``checkpoint_s`` is 0)."""
    if settings.checkpoint_s <= 0:
        return None
    return Path(settings.data_dir) / "state" / "pipeline.npz"


def broker_config(settings: Settings) -> BrokerConfig:
    """The broker connection of the settings (``mqtt_*``)."""
    pw = settings.mqtt_password.get_secret_value() if settings.mqtt_password else None
    return parse_broker_url(
        settings.mqtt_broker or "",
        username=settings.mqtt_username,
        password=pw,
        cafile=settings.mqtt_cafile,
        certfile=settings.mqtt_certfile,
        keyfile=settings.mqtt_keyfile,
    )


class WearLabelled(WearLabel):
    """``POST /api/tool-life/vb``'s answer (:meth:`LiveLoop.label_tool_wear`): the label
    taken, and whether the history recorded it on the tool's life."""

    recorded: bool


class EventsSummary(TypedDict):
    """The monitor's events for /metrics (:meth:`LiveLoop.events_summary`)."""

    total: dict[str, int]  # raised since the start, by kind
    unacked: int  # not yet acknowledged
    history_errors: int  # the history could not keep them


@dataclass(frozen=True)
class LoopParts:
    """What a :class:`LiveLoop` runs: the pipeline and the broker parts, if any."""

    pipeline: LivePipeline
    feed: DriveFeed | None = None
    estimates_out: EstimatesPublisher | None = None
    events_out: EventsPublisher | None = None
    #: the kept history (events, acknowledgements, tool lives); None: none kept
    history: HistoryStore | None = None


def loop_parts(settings: Settings) -> LoopParts:
    """The pipeline, the drive feed and the publishers the settings ask for: a real
    machine's feed from the broker (``source == "mqtt"``) or the simulated scenario; the
    estimates out when ``mqtt_publish_hz > 0``; the events and feed-hold commands out
    whenever a broker is set (``mqtt_broker``)."""
    feed: DriveFeed | None = None
    out: EstimatesPublisher | None = None
    events_out: EventsPublisher | None = None
    if settings.mqtt_broker:
        events_out = EventsPublisher(broker_config(settings), settings.mqtt_machine)
    if settings.source == "mqtt" or settings.mqtt_publish_hz > 0:
        cfg = broker_config(settings)
        if settings.source == "mqtt":
            feed = DriveFeed(
                cfg, settings.mqtt_machine, max_samples=10**7, max_seconds=settings.mqtt_buffer_s
            )
        if settings.mqtt_publish_hz > 0:
            out = EstimatesPublisher(
                cfg, settings.mqtt_machine, settings.mqtt_publish_hz, settings.public_url
            )
    if feed is not None:
        pipe = LivePipeline(seed=settings.seed, source=MqttSource(feed))
    elif settings.source == "opcua":
        pipe = LivePipeline(seed=settings.seed, source=opcua_source(settings))
    else:
        pipe = LivePipeline(settings.scenario, seed=settings.seed)
    if settings.model:  # the residual reports' effects for the axes' live models
        from server.pipeline.axis_part import axis_models

        pipe.set_axis_effects(axis_models(settings.model))
    return LoopParts(pipe, feed, out, events_out, history_store(settings))


def opcua_source(settings: Settings) -> OpcuaSource:
    """The OPC UA source of the settings (``opcua_*``; docs/opcua.md): the node map read
    and checked now, the connection made when the loop starts."""
    from server.pipeline.opcua_link import OpcuaSecurity
    from server.pipeline.opcua_source import OpcuaOptions
    from server.records.opcua_map import load_node_map

    assert settings.opcua_url is not None and settings.opcua_nodes is not None
    trust = tuple(Path(p.strip()) for p in settings.opcua_trust.split(",") if p.strip())
    sec = OpcuaSecurity(
        policy=settings.opcua_security,
        certificate=settings.opcua_cert,
        private_key=settings.opcua_key,
        trust=trust,
        cert_dir=settings.opcua_cert_dir or settings.data_dir / "opcua",
    )
    opts = OpcuaOptions(settings.opcua_url, settings.opcua_publishing_s, security=sec)
    return OpcuaSource(load_node_map(settings.opcua_nodes), opts)


def history_store(settings: Settings) -> HistoryStore | None:
    """The service's history (``history_url``, else SQLite in the data directory), migrated
    to the newest schema; None when ``history_url`` is ``none``."""
    url = settings.history_url
    if url is not None and url.strip().lower() == "none":
        return None
    return HistoryStore.for_data_dir(settings.data_dir, url, machine=settings.mqtt_machine)


class LiveLoop:
    """The background loop: pipeline stepping on a wall-clock schedule, frames to the hub.

    Every public method is thread-safe. Pipeline access (stepping, knobs, reset,
    snapshot) is serialised by one lock held for one block at a time; the routes use
    the methods of the facade below, never the pipeline or the lock.

    Parameters
    ----------
    settings, hub
        The service's settings and the client hub.
    pipeline
        The pipeline to run (default: the settings' simulated scenario).
    feed, estimates_out, events_out
        A drive feed, an estimates publisher and an events publisher
        (:func:`loop_parts`), started and stopped with the loop.
    history
        Where the events and the tool lives are kept (:class:`EventHistory`, the service's
        :class:`~server.records.history.HistoryStore` from :func:`loop_parts`; None:
        nowhere but memory). The latest events are reloaded from it at start.
    checkpoint
        The pipeline's checkpoint file (:func:`checkpoint_path`): resumed from at start,
        written every ``settings.checkpoint_s`` wall seconds and at stop. None: none.
    """

    def __init__(
        self,
        settings: Settings,
        hub: Hub,
        *,
        pipeline: LivePipeline | None = None,
        feed: DriveFeed | None = None,
        estimates_out: EstimatesPublisher | None = None,
        events_out: EventsPublisher | None = None,
        history: EventHistory | None = None,
        checkpoint: Path | None = None,
    ) -> None:
        self.settings = settings
        self.hub = hub
        #: a real machine's drive data from the broker (started and stopped with the loop)
        self.feed = feed
        #: the estimates on cutwatch/<machine>/estimates (started and stopped with the loop)
        self.estimates_out = estimates_out
        #: the events and feed-hold commands on cutwatch/<machine>/events, .../command
        self.events_out = events_out
        #: the machine's name, stamped on every event
        self.machine = settings.mqtt_machine
        #: the machine's runtime: pipeline, events, estimates, checkpoints, tool lives
        self.runtime = MachineRuntime(
            settings.mqtt_machine,
            pipeline or LivePipeline(settings.scenario, seed=settings.seed),
            events_out=events_out,
            estimates_out=estimates_out,
            history=history,
            checkpoint=checkpoint,
            writer=CheckpointWriter("cutwatch-checkpoint"),
            host="serve",
        )
        self.runtime.listeners.append(lambda rec: self.hub.publish_event(protocol.event_body(rec)))
        self._block_log: Any = None  # settings.block_log, opened by start()
        self.lock = self.runtime.lock
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.speed = float(settings.speed)
        self.paused = self.speed == 0.0
        self.block_n = max(1, round(settings.block_ms * 1e-3 / self.pipeline.sample_time))
        self.frame_period = 1.0 / settings.frame_hz
        self._lags: collections.deque[float] = collections.deque(maxlen=600)
        self._rate: collections.deque[tuple[float, float]] = collections.deque(maxlen=64)
        self.lag_s = 0.0
        self._p99, self._p99_at = 0.0, -math.inf
        self.stalls = 0
        self.blocks = 0
        self.seq = 0
        self.error: str | None = None
        self._pending: list[dict[str, np.ndarray]] = []
        self._hello_due = False  # the pipeline changed: clients need a new hello
        self.scene: StageScene | None = None  # the viser view, if started
        self.recording: Recording | None = None  # POST /api/record
        self._saved_at = time.monotonic()
        self._anchor()

    # ------------------------------------------------------------------ the runtime's
    @property
    def pipeline(self) -> LivePipeline:
        """The pipeline running (the runtime's)."""
        return self.runtime.pipeline

    @property
    def history(self) -> EventHistory | None:
        """The event history (events, acknowledgements, tool lives); None: memory only."""
        return self.runtime.history

    @property
    def checkpoint(self) -> Path | None:
        """The checkpoint file (``settings.checkpoint_s`` > 0)."""
        return self.runtime.checkpoint

    @property
    def checkpoint_status(self) -> CheckpointStatus:
        """What became of the checkpoint: path, resumed, resumed_t, saved_t, refused."""
        return self.runtime.checkpoint_status

    @property
    def events_total(self) -> dict[str, int]:
        """Events raised since the start, by kind."""
        return self.runtime.events_total

    @property
    def history_errors(self) -> int:
        """Writes of events the history refused (the loop went on)."""
        return self.runtime.history_errors

    # ------------------------------------------------------------------ control
    def _anchor(self) -> None:
        self._wall0 = time.monotonic()
        self._sim0 = self.pipeline.t

    def set_speed(self, speed: float) -> None:
        """Set simulated seconds per wall second (0 pauses)."""
        if not (math.isfinite(speed) and 0.0 <= speed <= MAX_SPEED):
            raise CutwatchError(f"speed: expected a value in [0, {MAX_SPEED:g}], got {speed!r}")
        with self.lock:
            self.speed = float(speed)
            self.paused = self.speed == 0.0
            self._anchor()
        self._wake.set()

    def pause(self) -> None:
        with self.lock:
            self.paused = True
        self._wake.set()

    def resume(self) -> None:
        with self.lock:
            if self.speed == 0.0:
                self.speed = 1.0
            self.paused = False
            self._anchor()
        self._wake.set()

    def reset(self) -> None:
        """Restart the simulation and every estimator from t = 0 (knob values kept)."""
        with self.lock:
            self.end_recording("the pipeline was reset")
            self.pipeline.reset()
            self._pending.clear()
            self._anchor()
        self._wake.set()

    def set_scenario(self, name: str) -> None:
        """Switch to another scenario: a fresh pipeline from t = 0, its default knobs."""
        self.set_pipeline(LivePipeline(name, seed=self.settings.seed))

    def set_pipeline(self, pipe: LivePipeline) -> None:
        """Run ``pipe`` from now on (a scenario, or a log replay); installed observer
        effects carry over. Not paused: a replay starts at once."""
        with self.lock:
            self.end_recording("the pipeline changed")
            self.runtime.set_pipeline(pipe)
            self.block_n = max(1, round(self.settings.block_ms * 1e-3 / pipe.sample_time))
            self._pending.clear()
            self._hello_due = True  # sent by the loop thread before its next frame
            if self.paused and not pipe.source.knobs_apply:  # a log or a live feed
                self.paused = False
                self.speed = self.speed or 1.0
            self._anchor()
        self._wake.set()

    # ------------------------------------------------------------------ thread
    def start(self) -> None:
        if self.feed is not None:
            self.feed.start()
        if isinstance(self.pipeline.source, OpcuaSource):
            self.pipeline.source.start()
        if self.estimates_out is not None:
            self.estimates_out.start()
        if self.events_out is not None:
            self.events_out.start()
        self.runtime.reload_events()
        if self.runtime.writer is not None:
            self.runtime.writer.start()
        if self.settings.block_log is not None:  # line-buffered: readable while it runs
            self._block_log = Path(self.settings.block_log).open("a", buffering=1)
        self._thread = threading.Thread(target=self._run, name="cutwatch-loop", daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 5.0) -> None:
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout)
            if not self._thread.is_alive():
                self.save_checkpoint()  # the state at shutdown
                self.runtime.keep_tool_lives()
        if self.runtime.writer is not None:
            self.runtime.writer.stop(timeout)
        rec = self.end_recording("the service stopped")
        if rec is not None:
            rec.wait(timeout)  # every block handed over is written before exit
        for part in (self.feed, self.estimates_out, self.events_out):
            if part is not None:
                part.stop()
        if isinstance(self.pipeline.source, OpcuaSource):
            self.pipeline.source.stop()
        if self._block_log is not None:
            self._block_log.close()

    def end_recording(self, reason: str) -> Recording | None:
        """End the recording in progress, if any (its writer finishes the file)."""
        with self.lock:
            rec, self.recording = self.recording, None
        if rec is not None:
            rec.end(reason)
        return rec

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def _run(self) -> None:
        # warm-up: the first block loads the compiled kernels (~1 s); run it off the clock
        # and start again from t = 0, so the schedule does not begin with a catch-up burst
        with self.lock:
            self.pipeline.step(self.block_n)
            self.pipeline.reset()
            self.pipeline.take_events()  # the warm-up block is run again: not its events
            self.pipeline.take_tool_changes()
            self.runtime.resume()
            self._anchor()
        last_frame = time.monotonic()
        # the first slot at the first block's due time at 1x (see FrameSlots)
        slots = FrameSlots(self.frame_period, last_frame + self.frame_period)
        try:
            while not self._stop.is_set():
                src = self.pipeline.source
                renewed = getattr(src, "renewed", None)  # a live feed's source
                if renewed is not None and getattr(src, "needs_rebuild", False):  # a new meta
                    pipe = LivePipeline(seed=self.settings.seed, source=renewed())
                    pipe.axis_effects = dict(self.pipeline.axis_effects)
                    pipe.reset()  # built with the axes' effects
                    pipe.carry(self.pipeline)  # the identified parameters go on
                    self.set_pipeline(pipe)
                with self.lock:
                    paused, speed = self.paused, self.speed
                    block_s = self.block_n * self.pipeline.sample_time
                    due = self._wall0 + (self.pipeline.t + block_s - self._sim0) / max(speed, 1e-9)
                    paced = getattr(self.pipeline.source, "paced", True)
                now = time.monotonic()
                if not paced:  # a live feed sets its own pace: take what has arrived
                    due = now
                if paused:
                    self.lag_s = 0.0
                    self._wake.wait(self.frame_period)
                    self._wake.clear()
                    if time.monotonic() - last_frame >= self.frame_period:
                        last_frame = time.monotonic()
                        self._publish()  # health keeps flowing while paused
                    continue
                if now < due:
                    self._wake.wait(min(due - now, self.frame_period))
                    self._wake.clear()
                    continue
                with self.lock:
                    if self.pipeline.finished:
                        self.paused = True  # a replayed log has ended
                        self.end_recording("the source has finished")
                    if self.paused or self._stop.is_set():
                        continue
                    t_from, taken = self.pipeline.t, time.time()
                    out, events = self.runtime.step(self.block_n)
                    got = len(out["t"]) > 0
                    if got and self._block_log is not None:
                        self._block_log.write(f"{t_from:.6f} {self.pipeline.t:.6f} {taken:.6f}\n")
                    if got and self.recording is not None and self.pipeline.last_block is not None:
                        self.recording.feed(self.pipeline.last_block)  # a queue put
                    if got:
                        self._pending.append(out)
                        self.blocks += 1
                    else:  # a live feed with nothing yet: time stands; wait, re-anchor
                        self._anchor()
                self.runtime.emit(events)  # at once, before anything else the block feeds
                if not got:
                    self._wake.wait(self.frame_period if paced else LIVE_POLL_S)
                    self._wake.clear()
                    if time.monotonic() - last_frame >= self.frame_period:
                        last_frame = time.monotonic()
                        self._publish()
                    continue
                self.runtime.keep_tool_lives()
                if self.scene is not None:
                    p = self.pipeline
                    self.scene.update(p.latest, p.workpiece_removed, p.t)
                if self.estimates_out is not None:
                    feed = self.feed.health() if self.feed is not None else None
                    self.runtime.estimates(out, time.time(), feed_health=feed)
                done = time.monotonic()
                lag = max(0.0, done - due)
                self.lag_s = lag
                self._lags.append(lag)
                self._rate.append((done, self.pipeline.t))
                if done - self._saved_at >= self.settings.checkpoint_s > 0:
                    self.save_checkpoint(wait=False)
                if lag > self.settings.max_lag_s:
                    self.stalls += 1
                    with self.lock:
                        self._anchor()
                # frames on their own wall schedule (see frame_slots): one per block at 1x,
                # coalesced after a stall
                if slots.due(done, block_s / max(speed, 1e-9)):
                    last_frame = done
                    self._publish()
        except Exception as exc:  # keep the service up and say why the loop stopped
            self.error = f"{type(exc).__name__}: {exc}"
            raise

    # ------------------------------------------------------------------ events
    def announce_event(self, ev: EventRecord) -> None:
        """An event changed (acknowledged): its new record (an :class:`Event`) goes to
        every client and replaces the kept copy; the status counts it as acknowledged."""
        self.runtime.announce(cast(EventRecord, Event.model_validate(ev).model_dump()))

    def add_client(self) -> tuple[ClientQueue, list[str]]:
        """Register a client (from its coroutine): its queue, and the event messages of
        the kept events not yet acknowledged (oldest first) to send after ``hello``.
        An event raised meanwhile is in one of the two, never in both."""
        q, backlog = self.runtime.listen(self.hub.add)
        return q, [protocol.event_body(r) for r in backlog]

    def recent_events(self) -> list[EventRecord]:
        """The kept events (at most :data:`~server.pipeline.runtime.EVENTS_KEPT`), newest
        first, as :class:`Event`."""
        return self.runtime.recent_events()

    def unacked(self) -> tuple[int, bool]:
        """Events not yet acknowledged, and whether one of them is an alarm or a feed hold."""
        return self.runtime.unacked()

    def monitor_status(self) -> MonitorStatus:
        """The status strip (:class:`MonitorStatus`): the pipeline's monitor status with
        the runtime's view of the acknowledgements: ``unacked``, and state ``alarm``
        while an alarm or a feed hold is not acknowledged (whatever the monitor's own
        state)."""
        return MonitorStatus.model_validate(self.runtime.monitor_status())

    def events_summary(self) -> EventsSummary:
        """The counts for /metrics: events by kind since the start, unacknowledged,
        history errors."""
        n, _ = self.unacked()
        by_kind = dict(self.events_total)
        return {"total": by_kind, "unacked": n, "history_errors": self.history_errors}

    def broker_status(self) -> dict[str, Any]:
        """The measurement source, and the broker parts when there are any."""
        src = self.pipeline.source
        out: dict[str, Any] = {"source": src.name}
        if self.feed is not None:
            out["feed"] = src.status()
        if isinstance(src, OpcuaSource):
            out["opcua"] = src.status()
        if self.estimates_out is not None:
            out["estimates_out"] = self.estimates_out.health()
        if self.events_out is not None:
            out["events_out"] = self.events_out.health()
        return out

    # ------------------------------------------------------------------ checkpoints
    def save_checkpoint(self, *, wait: bool = True) -> bool:
        """Write the pipeline's state to the checkpoint file (when the pipeline running is
        the one the service started with: not a replay or another scenario): taken under
        the lock, written here (``wait``) or by the runtime's writer thread. True when a
        state was taken."""
        self._saved_at = time.monotonic()
        return self.runtime.save(wait=wait)

    # ------------------------------------------------------------------ frames
    def _decimated(
        self,
    ) -> tuple[list[float | None], list[float | None], dict[str, list[float | None]]]:
        with self.lock:
            blocks, self._pending = self._pending, []
            grids = {c.name: c.grid for c in self.pipeline.channels()}
            sample_time = self.pipeline.sample_time
        if not blocks:
            return [], [], {}
        # at 1x a frame holds one block (20 Hz frames, 50 ms blocks): no copy then
        if len(blocks) == 1:
            merged = dict(blocks[0])
        else:
            merged = {k: np.concatenate([b[k] for b in blocks]) for k in blocks[0]}
        # a fixed stride per speed keeps the displayed sample rate steady across frames
        step = math.ceil(self.block_n / self.settings.display_points) * max(
            1, math.ceil(self.speed)
        )
        step = min(step, self.block_n * 64)
        # keep the samples whose index on the simulation's own grid is a multiple of the
        # stride: the displayed grid stays regular across frames, blocks and idle spells
        tt = merged.pop("t")
        g = np.rint(tt / sample_time).astype(np.int64)
        fast = g % step == 0
        slow = g % (step * protocol.SLOW_FACTOR) == 0
        t = protocol.samples(np.round(tt[fast], 6))  # 1 us: exact on the 0.4 ms grid
        ts = protocol.samples(np.round(tt[slow], 6))
        # every channel of a grid rounded in one pass (protocol.samples_rows: the same
        # values as protocol.samples per channel, ~4x cheaper for the 35 channels)
        ch: dict[str, list[float | None]] = {}
        for grid, mask in (("t", fast), ("ts", slow)):
            names = [k for k in merged if grids.get(k, "ts") == grid]
            if names:
                rows = np.vstack([merged[k][mask] for k in names])
                ch.update(zip(names, protocol.samples_rows(rows, DISPLAY_DIGITS), strict=True))
        ch = {k: ch[k] for k in merged}  # channel order as the pipeline gives it
        return t, ts, ch

    def hello(self) -> str:
        """The ``hello`` message of the current pipeline: its channels and charts as its
        parts declare them, the parts, the sample time, the knobs."""
        with self.lock:
            p = self.pipeline
            return protocol.hello(
                p.channels(),
                p.charts(),
                p.parts(),
                p.sample_time if getattr(p.source, "rate_known", True) else None,
                p.scenario,
                self.knob_values(),
            )

    def _publish(self) -> None:
        # runs on the loop thread only, so a new hello is ordered after every frame of
        # the old pipeline and before every frame of the new one
        with self.lock:
            hello_due, self._hello_due = self._hello_due, False
        if hello_due and self.hub.clients:
            self.hub.publish_hello(self.hello())
        self.seq += 1
        if self.hub.clients == 0:  # nobody listens: drop the blocks, skip the encoding
            with self.lock:
                self._pending.clear()
            return
        t, ts, ch = self._decimated()
        with self.lock:
            # rolling rms of the force estimates, rounded and JSON-safe
            accuracy = self.pipeline.accuracy(digits=protocol.ACCURACY_DIGITS)
            parts = self.pipeline.parts()
        frame = {
            "seq": self.seq,
            "wall": time.time(),
            "t": t,
            "ts": ts,
            "ch": ch,
            "health": self.health(),
            "knobs": self.knob_values(),
            "accuracy": accuracy,
            "status": self.monitor_status(),
            "parts": parts,
        }
        self.hub.publish(protocol.data_body(frame))

    # ------------------------------------------------------------------ status
    def realtime_factor(self) -> float:
        """Simulated seconds per wall second over the last ~64 blocks (0 when paused)."""
        if self.paused or len(self._rate) < 2:
            return 0.0
        (w0, s0), (w1, s1) = self._rate[0], self._rate[-1]
        if time.monotonic() - w1 > 1.0 or w1 <= w0:
            return 0.0
        return (s1 - s0) / (w1 - w0)

    def lag_p99(self) -> float:
        """p99 of the lag over the last 600 blocks (recomputed at most once a second)."""
        now = time.monotonic()
        if now - self._p99_at > 1.0:
            self._p99_at = now
            lags = np.fromiter(self._lags, float) if self._lags else np.zeros(1)
            self._p99 = float(np.percentile(lags, 99))
        return self._p99

    def health(self) -> LoopHealth:
        """The loop's health (:class:`~server.service.messages.LoopHealth`)."""
        return LoopHealth(
            sim_t=self.pipeline.t,
            speed=self.speed,
            paused=self.paused,
            lag_ms=1e3 * self.lag_s,
            lag_p99_ms=1e3 * self.lag_p99(),
            realtime_factor=self.realtime_factor(),
            clients=self.hub.clients,
            dropped_total=self.hub.dropped(),
            stalls=self.stalls,
        )

    def parts(self) -> list[PartInfo]:
        """The pipeline's parts: name, running, and why not."""
        with self.lock:
            return self.pipeline.parts()

    def machine_info(self) -> MachineInfo:
        """The machine and its parts (:meth:`LivePipeline.machine`)."""
        with self.lock:
            return self.pipeline.machine()

    def idle(self) -> str:
        """Why nothing is estimated (:meth:`LivePipeline.idle`; empty: something is)."""
        with self.lock:
            return self.pipeline.idle()

    def knob_values(self) -> dict[str, KnobValue]:
        with self.lock:
            return {k: v.value for k, v in self.pipeline.knobs().items()}

    # ------------------------------------------------------------------ facade (routes)
    @property
    def scenario(self) -> str:
        """The running scenario's name (a source's own name for a log or a feed)."""
        return self.pipeline.scenario

    @property
    def sim_t(self) -> float:
        """Time of the source [s]."""
        return self.pipeline.t

    @property
    def finished(self) -> bool:
        """The source hands out no more samples (a replayed log has ended)."""
        return self.pipeline.finished

    def knobs(self) -> dict[str, Knob]:
        """Every knob with its range and current value (frozen copies)."""
        with self.lock:
            return self.pipeline.knobs()

    def set_knobs(self, changes: Mapping[str, KnobValue]) -> dict[str, Knob]:
        """Set knobs, all or nothing; the knobs after the change.

        Raises
        ------
        ParameterError
            A refused change (nothing changed).
        """
        with self.lock:
            self.pipeline.set_knobs(changes)
            return self.pipeline.knobs()

    def snapshot(self) -> dict[str, object]:
        """The pipeline's snapshot (:meth:`LivePipeline.snapshot`), the checkpoint's
        status (``checkpoint``: path, resumed, resumed_t, saved_t, refused) and the truth
        of the latest :data:`INJECTED_KEPT` injected events (``injected``: kind, the first
        sample's time ``t`` and index, size, tool, line, part; for scoring, never given to
        a detector)."""
        with self.lock:
            snap = self.pipeline.snapshot()
            snap["checkpoint"] = dict(self.checkpoint_status)
            snap["injected"] = self.pipeline.process_truths()[-INJECTED_KEPT:]
            return snap

    def accuracy(self) -> AccuracySummary:
        """The rolling accuracy of the force estimates."""
        with self.lock:
            return self.pipeline.accuracy()

    def observer_effects(self) -> tuple[ObserverEffect, ...]:
        """The effects installed in the live observer."""
        with self.lock:
            return self.pipeline.effects

    def set_observer_effects(
        self, effects: tuple[ObserverEffect, ...]
    ) -> tuple[tuple[ObserverEffect, ...], float]:
        """Install effects (``()`` removes them); the effects installed and the time.

        Raises
        ------
        ParameterError
            An effect without its fitted coefficients.
        """
        with self.lock:
            self.pipeline.set_observer_effects(effects)
            return self.pipeline.effects, self.pipeline.t

    def axis_effects(self) -> tuple[dict[str, list[str]], float]:
        """Per axis, the names of the report's effects its live rigid model holds (before
        the feed's machine is known: as given), and the live time."""
        with self.lock:
            p = self.pipeline
            axes = p.part("axes")
            if axes is None:
                return {k: [e.name for e in v] for k, v in p.axis_effects.items()}, p.t
            return {n: [e.name for e in axes.effects[n]] for n in axes.with_effects}, p.t

    def set_axis_effects(self, effects: Mapping[str, tuple[Any, ...]]) -> float:
        """Load a residual report's effects into the axes' live models (``{}``: none);
        the time. The clients get a new hello (the channels changed)."""
        with self.lock:
            self.pipeline.set_axis_effects(effects)
            self._hello_due = True
            return self.pipeline.t

    def inject(
        self,
        kind: str,
        size: float | None = None,
        at_t: float | None = None,
        at_part: int | None = None,
    ) -> Scheduled:
        """Schedule an event in the simulator (:meth:`LivePipeline.inject`); what was
        scheduled.

        Raises
        ------
        ParameterError
            A value the pipeline refuses (naming the field), or a source without a
            simulator.
        """
        with self.lock:
            return self.pipeline.inject(kind, size=size, at_t=at_t, at_part=at_part)

    def label_tool_wear(self, tool: int, vb_mm: float) -> WearLabelled:
        """The VB measured [mm] at ``tool``'s latest ended life (the centre's wear part,
        :meth:`server.pipeline.centre_wear_part.CentreWearPart.label`).

        Raises
        ------
        ParameterError
            No wear part that takes labels (field ``tool``), no ended life of ``tool``, a
            VB out of range.
        """
        with self.lock:
            part = self.pipeline.part("centre_wear")
            if part is None:
                raise ParameterError(
                    "tool",
                    "a machine whose wear is read from its spindle's power (the centre_wear part)",
                    f"the {self.pipeline.scenario} pipeline",
                )
            out: WearLabel = part.label(tool, vb_mm)
            self.runtime.keep_tool_lives()  # the change itself, if not kept yet
        h = self.history
        row = None
        if isinstance(h, HistoryStore):
            row = h.measure_tool_life(int(out["tool"]), int(out["index"]), float(vb_mm))
        return {**out, "recorded": row is not None}

    def relearn(self, tool: int | None = None, program: str | None = None) -> Relearned:
        """Teach the monitor's limits again (:meth:`LivePipeline.relearn`): of one tool,
        one program, or all (both None); the tool, program and segments reset.

        Raises
        ------
        ParameterError
            A value the pipeline refuses (naming the field).
        """
        with self.lock:
            return self.pipeline.relearn(tool=tool, program=program)

    def start_recording(
        self,
        make: Callable[[RecordingSidecar], Recording],
        refuse: Callable[[], None] = lambda: None,
    ) -> Recording:
        """Start a recording of the running source: ``refuse()`` first (it raises when
        the loop's state allows none), then ``make(sidecar)``, both under the loop's
        lock, so no block or pipeline change falls between the check and the start."""
        from server.service.recording import source_sidecar

        with self.lock:
            refuse()
            rec = make(source_sidecar(self.pipeline.source, self.pipeline.scenario))
            self.recording = rec
            return rec
