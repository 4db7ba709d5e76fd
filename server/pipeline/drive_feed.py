"""A machine's drive data from the broker: subscribe, decode, check the order, buffer.

:class:`DriveFeed` subscribes to ``cutwatch/<machine>/drive`` and ``.../meta`` with
paho's network thread and hands checked samples to the live loop's thread through a
bounded buffer. What can go wrong with a stream of blocks is detected and counted, never
raised into the loop:

- a **gap** (blocks missing: ``seq`` jumps; or a time jump: ``t0`` is not where the
  previous block ended) -> the samples after it start a new segment, and the consumer is
  told (``Take.discontinuity``) so it resets the observers instead of differentiating
  across the hole;
- a **duplicate** (a block whose ``seq`` and ``t0`` were already taken) -> dropped;
- a block **out of order** (late: ``seq`` below the next expected one, not a duplicate)
  -> dropped (its samples' time has passed);
- a publisher **restart** (``seq`` back to 0) -> a new segment, like a gap;
- a **malformed** payload (schema, version, units, shape, values; :mod:`drive_wire`) ->
  counted by kind and skipped, logged once per kind per minute, not per message;
- a **flood** faster than the loop consumes -> the buffer keeps its newest ``max_samples``
  and counts what it dropped (a gap for the consumer);
- **units or sample time** that disagree with the retained meta -> counted as ``units``
  and skipped;
- **columns the machine does not name** (minor 2: a machine's block may carry more than
  this receiver's description) -> ignored and counted (``ignored_columns``, the names in
  ``health()["ignored_names"]``); the block is kept. An optional signal a block lacks
  comes out as NaN, so every sample handed out has every column of the machine.

The meta is a machine description (``common/machine.schema.json``; a meta of minor 0 is
one axis, :func:`server.records.drive_wire.machine_of`): ``description`` holds it.

The broker may be down at start or go away: paho reconnects with a backoff (1-30 s);
``health()`` says connected or not and the broker's last refusal (e.g. a wrong password)
— the service keeps running.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from common.arrays import F64
from common.machine_description import MachineDescription
from server.pipeline.broker import BrokerConfig, make_client, reason_text, topic
from server.records.drive_wire import (
    DriveBlock,
    WireError,
    check_block,
    decode_drive,
    decode_meta,
    machine_of,
)

log = logging.getLogger("cutwatch.mqtt")

#: counters in :meth:`DriveFeed.health` (also exported to /metrics)
COUNTERS = (
    "blocks",
    "samples",
    "gaps",
    "missing_blocks",
    "duplicates",
    "out_of_order",
    "restarts",
    "dropped_samples",
    "malformed_schema",
    "malformed_version",
    "malformed_units",
    "malformed_shape",
    "malformed_value",
    "meta_errors",
    "ignored_columns",
    "connects",
    "disconnects",
)


@dataclass
class Take:
    """What :meth:`DriveFeed.take` hands out: samples of one contiguous segment."""

    t: F64
    columns: dict[str, F64]
    #: True when these samples do not continue the previous ones (gap, restart, flood)
    discontinuity: bool = False
    reasons: list[str] = field(default_factory=list)
    #: the CNC's identities per sample (``tool``, ``line``, ``override``; NaN where a
    #: block sent none), empty when no block of the take sent any
    identities: dict[str, F64] = field(default_factory=dict)
    #: the running program's name of the take's last block that sent one
    program: str | None = None

    @property
    def n(self) -> int:
        return len(self.t)


class DriveFeed:
    """Subscribe to one machine's drive blocks; buffer checked samples for the loop.

    Parameters
    ----------
    cfg : BrokerConfig
        Broker address and credentials.
    machine : str
        The machine name (``cutwatch/<machine>/...``).
    max_samples : int
        Buffer bound in samples; beyond it the oldest samples are dropped (counted).
    max_seconds : float, optional
        The same bound in seconds of the feed's own sampling (the service's
        ``mqtt_buffer_s``); the smaller of the two applies.
    """

    def __init__(
        self,
        cfg: BrokerConfig,
        machine: str,
        max_samples: int = 25_000,
        max_seconds: float | None = None,
    ) -> None:
        self.cfg = cfg
        self.machine = machine
        self.max_samples = int(max_samples)
        self.max_seconds = max_seconds
        self.drive_topic = topic(machine, "drive")
        self.meta_topic = topic(machine, "meta")
        self.meta: dict[str, Any] | None = None
        #: the machine the meta describes (None until a meta arrived)
        self.description: MachineDescription | None = None
        #: names of the ignored columns seen (the first 16)
        self.ignored_names: list[str] = []
        #: counts the metas that changed what the observers are built from
        self.meta_generation = 0
        self.counts = dict.fromkeys(COUNTERS, 0)
        self.connected = False
        self.last_error = ""
        self._lock = threading.Lock()
        self._blocks: deque[tuple[DriveBlock, bool, list[str]]] = deque()
        self._buffered = 0
        self._next_seq: int | None = None
        self._next_t: float | None = None
        self._seen_meta = threading.Event()
        self._logged: dict[str, float] = {}
        self._pending_break: list[str] = []
        self._client: Any = None
        self._recent: deque[tuple[int, float]] = deque(maxlen=64)
        #: the publisher's wall clock of the newest block handed out (for latency)
        self.last_wall: float | None = None

    # -- the broker side (paho's network thread) ---------------------------------------

    def start(self) -> None:
        """Connect in the background (never blocks or raises for an absent broker)."""
        c: Any = make_client(self.cfg, client_id=f"cutwatch-serve-{self.machine}")
        c.on_connect = self._on_connect
        c.on_disconnect = self._on_disconnect
        c.on_message = self._on_message
        self._client = c
        c.connect_async(self.cfg.host, self.cfg.port, keepalive=self.cfg.keepalive)
        c.loop_start()

    def stop(self) -> None:
        c, self._client = self._client, None
        if c is not None:
            c.disconnect()
            c.loop_stop()

    def wait_meta(self, timeout: float) -> bool:
        return self._seen_meta.wait(timeout)

    def _say(self, kind: str, msg: str) -> None:
        now = time.monotonic()
        if now - self._logged.get(kind, -math.inf) >= 60.0:
            self._logged[kind] = now
            log.warning("machine %s: %s (further %s messages this minute not logged)",
                        self.machine, msg, kind)  # fmt: skip

    def _on_connect(self, client: Any, _u: object, _f: object, rc: Any, _p: object = None) -> None:
        if getattr(rc, "is_failure", False):
            self.connected = False
            self.last_error = f"broker {self.cfg.describe()} refused: {reason_text(rc)}"
            self._say("connect", self.last_error)
            return
        self.connected = True
        self.last_error = ""
        self.counts["connects"] += 1
        client.subscribe([(self.drive_topic, 0), (self.meta_topic, 1)])

    def _on_disconnect(
        self, _c: object, _u: object, _f: object, rc: Any, _p: object = None
    ) -> None:
        self.connected = False
        self.counts["disconnects"] += 1
        if getattr(rc, "is_failure", False) and "refused" not in self.last_error:
            # (a refused CONNACK is followed by a disconnect: keep the refusal's reason)
            self.last_error = f"broker {self.cfg.describe()}: disconnected ({reason_text(rc)})"
            self._say("disconnect", self.last_error)

    def _on_message(self, _c: object, _u: object, msg: Any) -> None:
        try:
            if msg.topic == self.meta_topic:
                self._meta(bytes(msg.payload))
            elif msg.topic == self.drive_topic:
                self.push(bytes(msg.payload))
        except Exception as exc:  # never let a message kill paho's thread
            self.counts["malformed_schema"] += 1
            self._say("internal", f"message on {msg.topic} skipped: {exc!r}")

    def push_meta(self, payload: bytes) -> None:
        """Take one meta payload (a worker's shared connection dispatches it here)."""
        self._meta(payload)

    def _meta(self, payload: bytes) -> None:
        try:
            meta = decode_meta(payload)
        except WireError as exc:
            self.counts["meta_errors"] += 1
            self._say("meta", f"meta skipped: {exc}")
            return
        machine = machine_of(meta)  # decode_meta checked it
        with self._lock:
            old = self.description
            if old is None or old != machine:
                self.meta_generation += 1
                if old is not None:
                    self._pending_break.append("meta changed")
            self.meta = meta
            self.description = machine
        self._seen_meta.set()

    # -- checks (also called directly by the tests) ------------------------------------

    def push(self, payload: bytes) -> None:
        """Decode one drive payload, check it against the meta and the sequence, buffer it."""
        try:
            b = decode_drive(payload)
        except WireError as exc:
            self.counts[f"malformed_{exc.kind}"] += 1
            self._say(exc.kind, f"drive block skipped: {exc}")
            return
        machine = self.description
        if machine is not None:
            want_ts = machine.sample_time
            if abs(b.sample_time - want_ts) > 1e-9 * want_ts:
                self.counts["malformed_units"] += 1
                self._say("units", f"sample_time {b.sample_time} != meta's {want_ts}: skipped")
                return
            try:
                checked = check_block(b, machine)
            except WireError as exc:
                self.counts[f"malformed_{exc.kind}"] += 1
                self._say(exc.kind, f"drive block skipped: {exc}")
                return
            if checked.ignored:
                self._ignored(checked.ignored)
            b = replace(b, columns=checked.columns)
        with self._lock:
            reasons = self._pending_break
            self._pending_break = []
            if self._next_seq is not None:
                assert self._next_t is not None
                tol = 0.5 * b.sample_time
                if b.seq == 0 and self._next_seq > 0 and b.t0 < self._next_t - tol:
                    self.counts["restarts"] += 1
                    reasons = [*reasons, "publisher restarted"]
                elif b.seq < self._next_seq:
                    if b.t0 < self._next_t - tol and b.seq >= self._next_seq - 64:
                        key = "duplicates" if self._was_taken(b) else "out_of_order"
                        self.counts[key] += 1
                        return
                    reasons = [*reasons, "sequence went back"]
                elif b.seq > self._next_seq:
                    self.counts["gaps"] += 1
                    self.counts["missing_blocks"] += b.seq - self._next_seq
                    reasons = [*reasons, f"{b.seq - self._next_seq} block(s) missing"]
                elif abs(b.t0 - self._next_t) > tol:
                    self.counts["gaps"] += 1
                    reasons = [*reasons, f"time jumped by {b.t0 - self._next_t:+.4g} s"]
            self._next_seq = b.seq + 1
            self._next_t = b.t_end
            self._recent.append((b.seq, b.t0))
            self.counts["blocks"] += 1
            self._blocks.append((b, bool(reasons), reasons))
            self._buffered += b.n
            limit = self.max_samples
            if self.max_seconds is not None:
                limit = min(limit, max(1, int(self.max_seconds / b.sample_time)))
            while self._buffered > limit and len(self._blocks) > 1:
                old, _, _ = self._blocks.popleft()
                self._buffered -= old.n
                self.counts["dropped_samples"] += old.n
                nb, _, nr = self._blocks[0]
                self._blocks[0] = (nb, True, [*nr, "buffer overflow: oldest samples dropped"])

    def _ignored(self, names: tuple[str, ...]) -> None:
        self.counts["ignored_columns"] += len(names)
        new = [k for k in names if k not in self.ignored_names]
        if new and len(self.ignored_names) < 16:
            self.ignored_names.extend(new[: 16 - len(self.ignored_names)])
            self._say("ignored", f"columns {new} are not in the machine's description: ignored")

    def _was_taken(self, b: DriveBlock) -> bool:
        return any(s == b.seq and abs(t - b.t0) < 0.5 * b.sample_time for s, t in self._recent)

    # -- the loop side ------------------------------------------------------------------

    @property
    def buffered(self) -> int:
        return self._buffered

    def take(self, n: int) -> Take:
        """Up to ``n`` buffered samples of one contiguous segment (possibly none)."""
        ts: list[F64] = []
        cols: dict[str, list[F64]] = {}
        idents: list[dict[str, F64] | None] = []
        program: str | None = None
        disc = False
        reasons: list[str] = []
        got = 0
        with self._lock:
            while self._blocks and got < n:
                b, brk, why = self._blocks[0]
                if brk and got > 0:
                    break  # the break starts the next take
                if brk:
                    disc, reasons = True, list(why)
                if b.wall is not None:
                    self.last_wall = b.wall
                program = b.program if b.program is not None else program
                k = min(n - got, b.n)
                t = b.t[:k]
                ts.append(t)
                for name, v in b.columns.items():
                    cols.setdefault(name, []).append(v[:k])
                ident = b.identities()
                idents.append(None if ident is None else {i: v[:k] for i, v in ident.items()})
                got += k
                self._buffered -= k
                if k == b.n:
                    self._blocks.popleft()
                else:  # keep the rest of the block, continuing (no break)
                    self._blocks[0] = (b.tail(k), False, [])
        self.counts["samples"] += got
        empty = np.zeros(0)
        return Take(
            t=np.concatenate(ts) if ts else empty,
            columns={k: np.concatenate(v) for k, v in cols.items()},
            discontinuity=disc,
            reasons=reasons,
            identities=_joined_identities(idents, [len(t) for t in ts]),
            program=program,
        )

    def health(self) -> dict[str, Any]:
        return {
            "machine": self.machine,
            "broker": self.cfg.describe(),
            "connected": self.connected,
            "meta": self.meta is not None,
            "error": self.last_error,
            "buffered_samples": self._buffered,
            "ignored_names": list(self.ignored_names),
            **self.counts,
        }


def _joined_identities(parts: list[dict[str, F64] | None], lengths: list[int]) -> dict[str, F64]:
    """Per-sample identities of consecutive pieces (NaN for a piece that sent none)."""
    if all(p is None for p in parts):
        return {}
    keys = ("tool", "line", "override")
    return {
        k: np.concatenate(
            [p[k] if p is not None else np.full(m, np.nan) for p, m in zip(parts, lengths)]
        )
        for k in keys
    }
