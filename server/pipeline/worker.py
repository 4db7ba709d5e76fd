"""Many machines in one process: the runtime of ``cutwatch worker``.

A :class:`Worker` runs one :class:`~server.pipeline.runtime.MachineRuntime` per machine it
owns (the runtime ``cutwatch serve`` wraps too: the same events, commands, estimates and
checkpoints), each on an :class:`~server.pipeline.mqtt_source.MqttSource` over its own
:class:`~server.pipeline.drive_feed.DriveFeed`, with no web server or 3D view per machine.
All machines share **one** broker connection:

- it subscribes to ``cutwatch/+/meta`` (retained, small, one message per machine) to
  learn the plant's machines, and adopts those it owns (:func:`harness.shards.owns`:
  its shard of a stable hash, or an explicit list); for each it subscribes to
  ``cutwatch/<machine>/drive`` only, so a worker receives only its own machines' blocks;
- paho's network thread dispatches each message by its topic to the machine's feed
  (decode, order checks, a bounded buffer: :mod:`~server.pipeline.drive_feed`);
- one loop thread steps every machine's pipeline by blocks of ``block_ms`` (default
  100 ms: estimates at 10 Hz), publishes ``cutwatch/<machine>/estimates`` (QoS 0, at
  ``publish_hz``) and the monitor's events on ``cutwatch/<machine>/events`` (QoS 1, the
  ``cutwatch.event`` wire schema; a ``feed_hold`` event also sends the command on
  ``cutwatch/<machine>/command``), all built by the runtime as the service builds them;
- every ``checkpoint_s`` it writes each machine's state to ``data_dir/state/<machine>.npz``
  (staggered; written by one writer thread), and all of them at :meth:`Worker.stop`
  (SIGTERM). A machine adopted by a (re)started worker resumes from its file: the wear,
  the identifiers' estimates and covariances carry on (docs/checkpoints.md); the first
  block after the restart is marked ``resumed``.

A worker also runs machines read from their CNCs' OPC UA servers
(:attr:`WorkerConfig.opcua`, ``cutwatch worker --opcua-machine``): each on its own
:class:`~server.pipeline.opcua_source.OpcuaSource` (its own client thread, security,
reconnects and health), stepped by the same loop as what has arrived, its estimates and
events published on the same broker as a broker machine's. The broker's metas of a
machine of that name are ignored.

A machine that sends a new meta (other sample time or nominal parameters) gets a new
pipeline, as in ``cutwatch serve``.
"""

from __future__ import annotations

import logging
import math
import random
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypedDict

import numpy as np

from common.errors import ParameterError
from common.jsonsafe import json_safe
from harness.shards import owns
from server.pipeline.broker import TOPIC_ROOT, BrokerConfig, make_client, reason_text
from server.pipeline.drive_feed import DriveFeed
from server.pipeline.estimates_out import EstimatesPublisher
from server.pipeline.events_out import EventsPublisher
from server.pipeline.live_pipeline import LivePipeline
from server.pipeline.mqtt_source import MqttSource
from server.pipeline.opcua_machines import OpcuaMachine
from server.pipeline.opcua_source import OpcuaSource
from server.pipeline.runtime import CheckpointStatus, CheckpointWriter, MachineRuntime
from server.pipeline.scenarios import STAGE_SCENARIO

log = logging.getLogger("cutwatch.worker")

#: the channels a machine's page shows (the rest are in the estimates message)
PAGE_CHANNELS = (
    "f_adaptive", "f_segment", "vb_est", "vb_limit", "life_left",
    "J_L_seg", "B_L_seg", "F_CL_seg", "J_L_adaptive",
)  # fmt: skip
#: a machine's backlog is taken in one step of up to this many blocks
CATCH_UP = 8
#: a machine's feed keeps at most this many seconds of samples (beyond: oldest dropped)
BUFFER_S = 10.0


@dataclass
class WorkerConfig:
    """What a worker runs (see :class:`Worker`).

    Attributes
    ----------
    shard, machines
        Its shard ``(I, N)`` or an explicit list of machine names (exactly one is set).
    data_dir
        Where ``state/<machine>.npz`` is kept (None: no checkpoints).
    block_ms
        Samples per pipeline step [ms of the feed]; 100 gives estimates at 10 Hz.
    publish_hz
        Estimates messages per machine per second.
    checkpoint_s
        Wall seconds between a machine's checkpoints (0: none written or read).
    dashboard
        The URL prefix of the machines' pages (``<prefix>/m/<machine>/``) for the fleet
        page's link; None: no link.
    opcua
        Machines read from their OPC UA servers (with these, shard and machines may both
        be None: no machine is taken from the broker).
    """

    shard: tuple[int, int] | None = None
    machines: frozenset[str] | None = None
    data_dir: Path | None = None
    block_ms: float = 100.0
    publish_hz: float = 10.0
    checkpoint_s: float = 5.0
    dashboard: str | None = None
    seed: int = 0
    opcua: tuple[OpcuaMachine, ...] = ()

    def __post_init__(self) -> None:
        if self.shard is None and self.machines is None and self.opcua:
            self.machines = frozenset()  # none from the broker
        if (self.shard is None) == (self.machines is None):
            raise ParameterError(
                "shard/machines", "exactly one of them", (self.shard, self.machines)
            )
        if not (10.0 <= self.block_ms <= 1000.0):
            raise ParameterError("block_ms", "10 .. 1000 ms", self.block_ms)
        if not (0 < self.publish_hz <= 50 and math.isfinite(self.publish_hz)):
            raise ParameterError("publish_hz", "0 < Hz <= 50", self.publish_hz)
        if not (self.checkpoint_s >= 0 and math.isfinite(self.checkpoint_s)):
            raise ParameterError("checkpoint_s", "a number of seconds >= 0", self.checkpoint_s)

    def describe(self) -> str:
        ua = f"opcua {','.join(m.name for m in self.opcua)}" if self.opcua else ""
        if self.shard is not None:
            return " + ".join(filter(None, [f"shard {self.shard[0]}/{self.shard[1]}", ua]))
        names = f"machines {','.join(sorted(self.machines))}" if self.machines else ""
        return " + ".join(filter(None, [names, ua]))


class WorkerHealth(TypedDict):
    """A worker's status (:meth:`Worker.health`, its ``GET /api/health`` and ``/metrics``);
    JSON-safe (a number not known is None)."""

    status: str
    worker: str
    broker: str
    connected: bool
    error: str
    machines: int
    receiving: int
    resumed: int
    dropped_samples: int
    opcua_connected: int
    loop_ms_p50: float
    loop_ms_max: float
    warm_s: float | None


@dataclass
class MachineRun:
    """One machine of a worker: its feed (None: an OPC UA machine), publishers and runtime
    (built at its first meta; an OPC UA machine's at the worker's start)."""

    name: str
    feed: DriveFeed | None
    out: EstimatesPublisher
    events_out: EventsPublisher
    runtime: MachineRuntime | None = None
    block_n: int = 0
    last_step: float = 0.0
    saved_at: float = 0.0
    #: recent force levels (rms of a block's adaptive estimate) for the machine's page
    levels: deque[tuple[float, float]] = field(default_factory=lambda: deque(maxlen=300))
    #: the OPC UA machine's connection (None: a broker machine)
    opcua: OpcuaMachine | None = None

    def feed_health(self) -> dict[str, Any]:
        """The feed's health: the broker feed's, or the OPC UA source's status."""
        if self.feed is not None:
            return self.feed.health()
        src = self.pipe.source if self.pipe is not None else None
        return src.status() if isinstance(src, OpcuaSource) else {"connected": False}

    @property
    def pipe(self) -> LivePipeline | None:
        """The machine's pipeline (None before its first meta)."""
        return self.runtime.pipeline if self.runtime is not None else None

    @property
    def blocks(self) -> int:
        return self.runtime.blocks if self.runtime is not None else 0

    @property
    def events(self) -> int:
        return sum(self.runtime.events_total.values()) if self.runtime is not None else 0

    @property
    def checkpoint(self) -> CheckpointStatus:
        return self.runtime.checkpoint_status.copy() if self.runtime is not None else {}


class Worker:
    """The machines of one shard (module docstring). :meth:`start` / :meth:`stop`."""

    def __init__(self, broker: BrokerConfig, cfg: WorkerConfig, name: str = "") -> None:
        self.broker = broker
        self.cfg = cfg
        self.name = name or cfg.describe()
        self.runs: dict[str, MachineRun] = {}
        self.connected = False
        self.last_error = ""
        self.started_wall = time.time()
        self.loop_s: deque[float] = deque(maxlen=200)  # wall time of a pass over all machines
        self.error = ""
        self.warm_s = math.nan  # seconds the kernels took to load at start
        self._lock = threading.Lock()  # guards self.runs (paho's thread adds machines)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.writer = CheckpointWriter("cutwatch-worker-checkpoints")
        self._client: Any = None
        self._ready = threading.Event()  # the kernels are compiled

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        """Start the loop thread: it compiles the kernels, then connects (so no block
        waits in a buffer while it compiles); machines come as their metas arrive."""
        c: Any = make_client(self.broker, client_id=f"cutwatch-worker-{self.name}")
        c.on_connect = self._on_connect
        c.on_disconnect = self._on_disconnect
        c.on_message = self._on_message
        self._client = c
        for m in self.cfg.opcua:
            self.adopt_opcua(m)
        for run in list(self.runs.values()):
            run.out.share(c)
            run.events_out.share(c)
        self._thread = threading.Thread(target=self._run, name="cutwatch-worker", daemon=True)
        self._thread.start()
        self.writer.start()

    def stop(self, timeout: float = 10.0) -> None:
        """Stop the loop, write every machine's checkpoint, disconnect."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
        self.writer.stop(timeout)
        with self._lock:
            runs = list(self.runs.values())
        for run in runs:  # the newest state of each, written here
            self._save(run)
            if run.opcua is not None and run.pipe is not None:
                run.pipe.source.stop()  # type: ignore[attr-defined]
        c, self._client = self._client, None
        if c is not None:
            c.disconnect()
            c.loop_stop()

    @property
    def ready(self) -> bool:
        return self._ready.is_set() and self.connected and not self.error

    # ------------------------------------------------------------------ the broker side
    def _on_connect(self, client: Any, _u: object, _f: object, rc: Any, _p: object = None) -> None:
        if getattr(rc, "is_failure", False):
            self.connected = False
            self.last_error = f"broker {self.broker.describe()} refused: {reason_text(rc)}"
            log.warning("cutwatch worker: %s", self.last_error)
            return
        self.connected, self.last_error = True, ""
        subs = [(f"{TOPIC_ROOT}/+/meta", 1)]
        with self._lock:
            runs = list(self.runs.values())
        for run in runs:
            run.out.connected = run.events_out.connected = True
            if run.feed is not None:
                run.feed.connected = True
                subs.append((run.feed.drive_topic, 0))
        client.subscribe(subs)

    def _on_disconnect(
        self, _c: object, _u: object, _f: object, rc: Any, _p: object = None
    ) -> None:
        self.connected = False
        with self._lock:
            runs = list(self.runs.values())
        for run in runs:
            run.out.connected = run.events_out.connected = False
            if run.feed is not None:
                run.feed.connected = False
                run.feed.counts["disconnects"] += 1
        if getattr(rc, "is_failure", False):
            self.last_error = f"broker {self.broker.describe()}: disconnected ({reason_text(rc)})"

    def _on_message(self, _c: object, _u: object, msg: Any) -> None:
        parts = str(msg.topic).split("/")
        if len(parts) != 3 or parts[0] != TOPIC_ROOT:
            return
        _, machine, leaf = parts
        run = self.runs.get(machine)
        try:
            if leaf == "meta":
                if run is None:
                    if not owns(machine, self.cfg.shard, self.cfg.machines):
                        return
                    run = self.adopt(machine)
                if run.feed is not None:  # an OPC UA machine of that name: not the broker's
                    run.feed.push_meta(bytes(msg.payload))
            elif leaf == "drive" and run is not None and run.feed is not None:
                run.feed.push(bytes(msg.payload))
        except Exception as exc:  # never let a message kill paho's thread
            log.warning("cutwatch worker: message on %s skipped: %r", msg.topic, exc)

    def adopt(self, machine: str) -> MachineRun:
        """Start owning ``machine``: its feed and publisher, its drive subscription."""
        with self._lock:
            run = self.runs.get(machine)
            if run is not None:
                return run
            feed = DriveFeed(self.broker, machine, max_samples=10**7, max_seconds=BUFFER_S)
            dash = f"{self.cfg.dashboard.rstrip('/')}/m/{machine}/" if self.cfg.dashboard else None
            out = EstimatesPublisher(self.broker, machine, self.cfg.publish_hz, dash)
            run = MachineRun(machine, feed, out, EventsPublisher(self.broker, machine))
            self.runs[machine] = run
        c = self._client
        if c is not None and self.connected:
            feed.connected = out.connected = run.events_out.connected = True
            feed.counts["connects"] += 1
            out.share(c)
            run.events_out.share(c)
            c.subscribe(feed.drive_topic, qos=0)
        elif c is not None:
            out.share(c)
            run.events_out.share(c)
        log.info("cutwatch worker %s: owns %s", self.name, machine)
        return run

    def adopt_opcua(self, m: OpcuaMachine) -> MachineRun:
        """Own the OPC UA machine ``m``: its runtime on its own source (its client thread
        started here, reconnecting by itself), its publishers on the worker's broker."""
        dash = f"{self.cfg.dashboard.rstrip('/')}/m/{m.name}/" if self.cfg.dashboard else None
        out = EstimatesPublisher(self.broker, m.name, self.cfg.publish_hz, dash)
        run = MachineRun(m.name, None, out, EventsPublisher(self.broker, m.name), opcua=m)
        src = m.source()
        self._new_runtime(run, LivePipeline(seed=self.cfg.seed, source=src))
        self._set_grid(run)
        with self._lock:
            self.runs[m.name] = run
        src.start()
        log.info("cutwatch worker %s: owns %s (OPC UA %s)", self.name, m.name, m.options.url)
        return run

    # ------------------------------------------------------------------ the loop
    def _run(self) -> None:
        try:
            w0 = time.monotonic()
            # compile the kernels once, up front: the seeds' stage scenario's, whose
            # observers a feed's two-inertia machine runs
            LivePipeline(STAGE_SCENARIO, seed=self.cfg.seed).step(250)
            self.warm_s = time.monotonic() - w0
            self._ready.set()
            c, b = self._client, self.broker
            if c is not None:
                c.connect_async(b.host, b.port, keepalive=b.keepalive)
                c.loop_start()
            while not self._stop.is_set():
                t0 = time.monotonic()
                with self._lock:
                    runs = list(self.runs.values())
                worked = False
                for run in runs:
                    worked |= self._serve(run)
                    if self._save_due(run, t0):
                        self._save(run, wait=False)
                if worked:
                    self.loop_s.append(time.monotonic() - t0)
                else:
                    self._stop.wait(0.01)
        except Exception as exc:  # say why the loop stopped (health, probes)
            self.error = f"{type(exc).__name__}: {exc}"
            log.exception("cutwatch worker: loop stopped")
            raise

    def _serve(self, run: MachineRun) -> bool:
        """Step one machine if a block (or the rest of a stalled one) has arrived;
        publish its estimates and events. True when it stepped."""
        feed = run.feed
        if run.pipe is None or run.pipe.source.needs_rebuild:  # type: ignore[attr-defined]
            if feed is not None and feed.meta is None:
                return False
            self._build(run)
        pipe = run.pipe
        assert pipe is not None
        now = time.monotonic()
        if feed is None:  # an OPC UA source: what its grid has ready, a block at most
            # per block's time (it sets its own pace, as in ``cutwatch serve``)
            if now - run.last_step < 1e-3 * self.cfg.block_ms:
                return False
            return self._step(run, run.block_n, now)
        have = feed.buffered
        stalled = have > 0 and now - run.last_step > 2e-3 * self.cfg.block_ms
        if have < run.block_n and not stalled:
            return False
        # one step per machine per pass (round robin: a machine's backlog never starves
        # the others); a backlog is taken in one longer step, up to CATCH_UP blocks: the
        # estimates do not depend on the block length (bit-identical, docs/plant.md) and
        # a longer block costs less per sample, so a worker that fell behind catches up
        k = min(max(have // run.block_n, 1), CATCH_UP)
        return self._step(run, k * run.block_n, now)

    def _step(self, run: MachineRun, n: int, now: float) -> bool:
        """Step ``n`` samples (fewer: what has arrived), publish; True when it stepped."""
        rt = run.runtime
        assert rt is not None
        out, events = rt.step(n)
        stepped = len(out["t"]) > 0
        if stepped:
            rt.emit(events)
            rt.keep_tool_lives()
            f = out.get("f_adaptive")
            if f is not None and f.size:
                a = f[np.isfinite(f)]
                if a.size:
                    run.levels.append((float(out["t"][-1]), float(np.sqrt(a @ a / a.size))))
            rt.estimates(out, time.time(), feed_health=run.feed_health())
        run.last_step = now
        return stepped

    def _build(self, run: MachineRun) -> None:
        """A pipeline on the machine's feed; the first one in a runtime resumed from the
        machine's checkpoint if there is one (a new meta: a new pipeline, the runtime
        and its counts go on)."""
        if run.runtime is not None:
            old = run.runtime.pipeline
            src = old.source.renewed()  # type: ignore[attr-defined]
            pipe = LivePipeline(seed=self.cfg.seed, source=src)
            pipe.carry(old)  # the identified parameters go on (a new rate: designed again)
            run.runtime.set_pipeline(pipe)
        else:
            assert run.feed is not None
            self._new_runtime(run, LivePipeline(seed=self.cfg.seed, source=MqttSource(run.feed)))
        self._set_grid(run)

    def _new_runtime(self, run: MachineRun, pipe: LivePipeline) -> None:
        run.runtime = MachineRuntime(
            run.name,
            pipe,
            events_out=run.events_out,
            estimates_out=run.out,
            checkpoint=self._path(run.name),
            writer=self.writer,
            host=f"worker {self.name}",
        )
        run.runtime.resume()

    def _set_grid(self, run: MachineRun) -> None:
        assert run.runtime is not None
        run.block_n = max(1, round(self.cfg.block_ms * 1e-3 / run.runtime.pipeline.sample_time))
        # the first step waits for a whole block too (a stall: for 2 blocks' time), so the
        # blocks, and the estimates with them, fall on the machine's block grid
        run.last_step = time.monotonic()
        # the first checkpoint at a random point of the period: machines built together
        # (a worker's start) do not all write at once, every period after
        run.saved_at = time.monotonic() - random.uniform(0.0, self.cfg.checkpoint_s)

    # ------------------------------------------------------------------ checkpoints
    def _path(self, machine: str) -> Path | None:
        if self.cfg.data_dir is None or self.cfg.checkpoint_s <= 0:
            return None
        return self.cfg.data_dir / "state" / f"{machine}.npz"

    def _save_due(self, run: MachineRun, now: float) -> bool:
        return (
            run.runtime is not None
            and self.cfg.checkpoint_s > 0
            and now - run.saved_at >= self.cfg.checkpoint_s
        )

    def _save(self, run: MachineRun, *, wait: bool = True) -> None:
        """Take the machine's state (in the loop's thread: the pipeline is not shared)
        and write it: here (``wait``), or by the writer thread, whose file system waits
        (the fsync of an atomic write, ~20 ms here) do not hold up the loop."""
        run.saved_at = time.monotonic()
        if run.runtime is not None:
            run.runtime.save(wait=wait)

    def adopt_saved(self) -> list[str]:
        """Own, at once, the machines of this worker that have a checkpoint file (their
        drive topics are subscribed before their retained metas arrive)."""
        if self._path("x") is None:
            return []
        assert self.cfg.data_dir is not None
        names = sorted(p.stem for p in (self.cfg.data_dir / "state").glob("*.npz"))
        ua = {m.name for m in self.cfg.opcua}
        mine = [n for n in names if owns(n, self.cfg.shard, self.cfg.machines) and n not in ua]
        for n in mine:
            self.adopt(n)
        return mine

    # ------------------------------------------------------------------ views
    def machine(self, name: str) -> dict[str, Any] | None:
        """One machine as its page shows it (None: not this worker's)."""
        run = self.runs.get(name)
        if run is None:
            return None
        pipe, rt = run.pipe, run.runtime
        latest = pipe.latest if pipe is not None else {}
        return json_safe(
            {
                "machine": name,
                "worker": self.name,
                "t": pipe.t if pipe is not None else None,
                # the machine's clock at the pipeline's t = 0 (MqttSource.feed_origin)
                "feed_origin_s": (
                    getattr(pipe.source, "feed_origin", None) if pipe is not None else None
                ),
                "blocks": run.blocks,
                "events": run.events,
                "latest": {k: latest.get(k, math.nan) for k in PAGE_CHANNELS},
                "status": rt.monitor_status() if rt is not None else None,
                "parts": pipe.parts() if pipe is not None else [],
                "feed": pipe.source.status() if pipe is not None else run.feed_health(),
                "checkpoint": dict(run.checkpoint),
                "estimates_out": run.out.health(),
                "levels": list(run.levels),
            }
        )

    def health(self) -> WorkerHealth:
        with self._lock:
            runs = list(self.runs.values())
        loop = np.asarray(self.loop_s) if self.loop_s else np.zeros(1)
        return json_safe(
            {
                "status": "ok" if self.ready else ("error" if self.error else "starting"),
                "worker": self.name,
                "broker": self.broker.describe(),
                "connected": self.connected,
                "error": self.error or self.last_error,
                "machines": len(runs),
                "receiving": sum(r.pipe is not None and r.blocks > 0 for r in runs),
                "resumed": sum(bool(r.checkpoint.get("resumed")) for r in runs),
                "dropped_samples": sum(
                    r.feed.counts["dropped_samples"] for r in runs if r.feed is not None
                ),
                "opcua_connected": sum(
                    bool(r.feed_health().get("connected")) for r in runs if r.opcua is not None
                ),
                "loop_ms_p50": 1e3 * float(np.median(loop)),
                "loop_ms_max": 1e3 * float(loop.max()),
                "warm_s": self.warm_s,
            }
        )
