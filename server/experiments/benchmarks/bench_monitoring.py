"""Alarms that act: from the block holding an event's first sample to the feed-hold command
on a real Mosquitto, through a real ``cutwatch serve`` at 1x.

What runs, each real: Debian's ``mosquitto`` on a free loopback port; ``cutwatch serve``
as a child process (its own data directory, no viser, ``--broker``, ``--machine bench``,
the default scenario: the part program with the process monitor); in this process a paho
subscriber of ``cutwatch/bench/command`` and ``cutwatch/bench/events``, and one WebSocket
client reading every message (a dashboard open, so the loop encodes and sends its frames
as it does in use). A served process rather than the loop in-process: the latency then
holds what ``serve`` adds (uvicorn and the WebSocket in the same process, sharing the
GIL with the loop), and ``server.experiments`` does not import ``server.service``.

The measured latency of one event is ``w1 - w0``:

``w0``
    the wall clock (``time.time()``, unix s) at which the service's loop took the block
    holding the event's first sample: read just before the loop calls
    ``LivePipeline.step`` for that block. The loop writes it to its block log
    (``CUTWATCH_BLOCK_LOG``: one line per block, the source time of its first sample, of
    the sample after its last, and that wall time); the block is the one whose span
    holds the injected event's first sample, from its truth (``GET /api/snapshot``,
    ``pipeline.injected[].t``: the simulator's, never given to a detector).
``w1``
    the wall clock when this process's paho callback receives the ``feed_hold`` command
    carrying that event's id (same host, same clock).

So it holds the detection delay at 1x (the breakage detector needs up to two spindle
revolutions of samples after the first, and at 1x those arrive in real time: one
revolution is 33-50 ms in the default program), the blocks' computation, the publish,
the broker and the delivery. The target: p99 < 100 ms at 1x.

Procedure: teach-in at ``FAST_SPEED`` x with ``teach_parts`` 2 until part 3 begins; then
per event: inject a tooth breakage (0.4 mm, the clear size) into the next part (``POST
/api/control`` ``at_part``: the middle of that part's first cut, a place the monitor
has taught), run at ``FAST_SPEED`` x until this part's last operation (line
``LAST_OP_LINE``), then at 1x until the command comes (``COMMAND_TIMEOUT_S`` at most:
else a miss, counted); the broken tool is replaced at the end of its part, and the next
event goes into the part after. An event counts only if the ``PACED_BLOCKS`` blocks
before its block ran at 1x (from the block log; else ``not_at_1x``). ``EVENTS`` events
(``QUICK_EVENTS`` with ``--quick``); ``repeats`` is not used (one run of that many
events). A feed hold that is not the injected breakage's (a false alarm) is counted in
``other_feed_holds``, not timed. Heavy-ish: one service, ~7 s of 1x per event.

Why ``at_part`` and not "now": a breakage injected at an arbitrary instant is not always
found by the monitor (a detection-rate question, measured by ``cutwatch reproduce
process-monitoring``, not a latency one); this benchmark times the path of the events
that are found, at the place the reproduction calls clear.
"""

from __future__ import annotations

import contextlib
import json
import os
import queue
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np

from server.experiments.benchmarks import Figures
from server.experiments.benchmarks._local import free_port, mosquitto

MACHINE = "bench"
EVENTS = 40
QUICK_EVENTS = 5
FAST_SPEED = 20.0
#: the program's last operation (T2's contour): the loop goes back to 1x when it starts
LAST_OP_LINE = 60
#: blocks before an event's block that must have run at 1x for the event to count
PACED_BLOCKS = 20
COMMAND_TIMEOUT_S = 30.0
TARGET_P99_MS = 100.0


@contextlib.contextmanager
def _service(broker_port: int, d: Path) -> Iterator[tuple[str, Path]]:
    """``cutwatch serve`` at 1x on a free port; its base URL and its block log."""
    port = free_port()
    log = d / "blocks.log"
    env = dict(
        os.environ,
        CUTWATCH_DATA_DIR=str(d / "data"),
        CUTWATCH_BLOCK_LOG=str(log),
        CUTWATCH_CHECKPOINT_S="0",
    )
    # the seeds' scenario (its process monitor), as before the centre became the default
    cmd = [sys.executable, "-m", "server.cli.main", "serve", "--port", str(port), "--no-viser",
           "--scenario", "default", "--broker", f"mqtt://127.0.0.1:{broker_port}",
           "--machine", MACHINE]  # fmt: skip
    out = (d / "serve.out").open("w")
    proc = subprocess.Popen(cmd, env=env, stdout=out, stderr=subprocess.STDOUT)
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 120
        while True:
            if proc.poll() is not None:
                raise RuntimeError(f"cutwatch serve exited: {(d / 'serve.out').read_text()[-800:]}")
            with contextlib.suppress(httpx.HTTPError):
                h = httpx.get(f"{base}/api/health", timeout=2).json()
                if h.get("events_out", {}).get("connected"):
                    break
            if time.monotonic() > deadline:
                raise RuntimeError("cutwatch serve did not come up in 120 s")
            time.sleep(0.2)
        yield base, log
    finally:
        proc.terminate()
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
        out.close()


class _Listener:
    """The paho subscriber: commands with their arrival wall time, events by id."""

    def __init__(self, port: int) -> None:
        import paho.mqtt.client as mqtt

        self.commands: queue.Queue[tuple[float, dict[str, Any]]] = queue.Queue()
        self.events: dict[str, dict[str, Any]] = {}
        ready = threading.Event()
        c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="cutwatch-bench-edge")

        def on_message(_c: object, _u: object, m: Any) -> None:
            w1 = time.time()  # first: the arrival
            body = json.loads(m.payload)
            if m.topic.endswith("/command"):
                self.commands.put((w1, body))
            else:
                self.events[body["id"]] = body

        c.on_message = on_message
        c.on_subscribe = lambda *_a: ready.set()
        c.connect("127.0.0.1", port)
        c.loop_start()
        c.subscribe([(f"cutwatch/{MACHINE}/command", 1), (f"cutwatch/{MACHINE}/events", 1)])
        if not ready.wait(10):
            raise RuntimeError("the subscriber was not subscribed in 10 s")
        self.client = c

    def close(self) -> None:
        self.client.loop_stop()
        self.client.disconnect()


def _dashboard(url: str, stop: threading.Event) -> threading.Thread:
    """A WebSocket client reading every message until ``stop``."""
    from websockets.sync.client import connect

    def read() -> None:
        with connect(url, max_size=None) as ws:
            while not stop.is_set():
                with contextlib.suppress(TimeoutError):
                    ws.recv(timeout=0.5)

    th = threading.Thread(target=read, name="bench-dashboard", daemon=True)
    th.start()
    return th


def _block_taken(log: Path, t_first: float) -> float:
    """The wall time the loop took the block whose span holds ``t_first`` (NaN: none)."""
    for line in reversed(log.read_text().splitlines()):
        a, b, w = (float(x) for x in line.split())
        if a - 1e-9 <= t_first < b - 1e-9:
            return w
    return float("nan")


def _snapshot(base: str) -> dict[str, Any]:
    snap: dict[str, Any] = httpx.get(f"{base}/api/snapshot", timeout=5).json()
    return snap


def _control(base: str, body: dict[str, Any]) -> dict[str, Any]:
    r = httpx.post(f"{base}/api/control", json=body, timeout=10)
    if r.status_code != 200:
        raise RuntimeError(f"POST /api/control {body}: {r.status_code} {r.text[:300]}")
    out: dict[str, Any] = r.json()
    return out


def _wait_until(base: str, part: int, line: int, timeout: float = 300.0) -> None:
    """Until the program runs ``line`` (or a later one) of ``part``, or a later part."""
    deadline = time.monotonic() + timeout
    while True:
        st = _snapshot(base)["status"]
        if st["part"] > part or (st["part"] == part and st["line"] >= line):
            return
        if time.monotonic() > deadline:
            raise RuntimeError(f"line {line} of part {part} did not come in {timeout:g} s")
        time.sleep(0.05)


def _paced(log: Path, w0: float) -> bool:
    """The loop ran at 1x before ``w0``: the ``PACED_BLOCKS`` blocks before the event's
    block took at least 80 % of their simulated time in wall time."""
    rows = [tuple(float(x) for x in ln.split()) for ln in log.read_text().splitlines()]
    before = [r for r in rows if r[2] <= w0][-PACED_BLOCKS - 1 :]
    if len(before) <= PACED_BLOCKS:
        return False
    sim = before[-1][0] - before[0][0]
    return before[-1][2] - before[0][2] >= 0.8 * sim


def _one_event(base: str, log: Path, sub: _Listener, part: int) -> dict[str, float]:
    """Inject a breakage into the next part, run at 1x from the last operation of this
    one, and time its command (see the module docstring)."""
    n_before = len(_snapshot(base)["pipeline"]["injected"])
    _control(base, {"action": "inject", "kind": "breakage", "at_part": part + 1})
    _wait_until(base, part, LAST_OP_LINE)
    _control(base, {"action": "speed", "value": 1.0})
    other = 0
    deadline = time.monotonic() + COMMAND_TIMEOUT_S
    while True:
        left = deadline - time.monotonic()
        if left <= 0:
            snap = _snapshot(base)
            print(f"  missed: no command in {COMMAND_TIMEOUT_S:g} s; injected "
                  f"{snap['pipeline']['injected'][n_before:]}, status {snap['status']}",
                  file=sys.stderr)  # fmt: skip
            return {"missed": 1.0, "other": float(other), "part": float(part + 1)}
        try:
            w1, cmd = sub.commands.get(timeout=left)
        except queue.Empty:
            continue
        truths = _snapshot(base)["pipeline"]["injected"]
        ev_deadline = time.monotonic() + 5
        while cmd["event_id"] not in sub.events and time.monotonic() < ev_deadline:
            time.sleep(0.01)
        ev = sub.events.get(cmd["event_id"], {})
        if len(truths) <= n_before or ev.get("kind") != "breakage":
            other += 1  # a feed hold that is not this breakage's (a false alarm)
            continue
        t_first = float(truths[-1]["t"])
        w0 = _block_taken(log, t_first)
        return {
            "latency_ms": 1e3 * (w1 - w0),
            "detect_ms": 1e3 * (float(cmd["t"]) - t_first),
            "paced": float(_paced(log, w0)),
            "part": float(truths[-1]["part"]),
            "other": float(other),
        }


def measure(*, repeats: int, quick: bool) -> Figures:
    """Time ``EVENTS`` breakages (``QUICK_EVENTS`` quick) from their first sample's block
    to their command on the broker; ``repeats`` unused (see the module docstring)."""
    del repeats
    n_events = QUICK_EVENTS if quick else EVENTS
    bport = free_port()
    rows: list[dict[str, float]] = []
    with tempfile.TemporaryDirectory(prefix="cutwatch-bench-mon-") as tmp, mosquitto(bport):
        d = Path(tmp)
        sub = _Listener(bport)
        stop = threading.Event()
        try:
            with _service(bport, d) as (base, log):
                reader = _dashboard(base.replace("http://", "ws://") + "/ws", stop)
                httpx.patch(f"{base}/api/params", json={"teach_parts": 2}, timeout=10)
                _control(base, {"action": "speed", "value": FAST_SPEED})
                _wait_until(base, 3, 0)  # parts 0 and 1 taught, part 2 watched whole
                part = 3
                while len(rows) < n_events:
                    row = _one_event(base, log, sub, part)
                    rows.append(row)
                    print(f"  event {len(rows)}: {row}", file=sys.stderr)
                    _control(base, {"action": "speed", "value": FAST_SPEED})
                    part = int(row["part"])
                metrics = httpx.get(f"{base}/metrics", timeout=5).text
                stop.set()
                reader.join(5)
        finally:
            stop.set()
            sub.close()
    return _summary(rows, metrics)


def _summary(rows: list[dict[str, float]], metrics: str) -> Figures:
    timed = [r for r in rows if "latency_ms" in r and r["paced"]]
    lat = np.array([r["latency_ms"] for r in timed])
    det = np.array([r["detect_ms"] for r in timed])
    holds = next(
        (int(float(ln.split()[1])) for ln in metrics.splitlines()
         if ln.startswith("cutwatch_commands_published_total ")),
        -1,
    )  # fmt: skip
    p99 = float(np.percentile(lat, 99)) if lat.size else float("nan")
    return {
        "configuration": "cutwatch serve at 1x (default scenario, 50 ms blocks), one "
        "WebSocket client, Mosquitto on loopback; tooth breakages (0.4 mm) injected into "
        "the next part's first cut",
        "events": int(lat.size),
        "missed": int(sum(r.get("missed", 0.0) for r in rows)),
        "not_at_1x": int(sum("latency_ms" in r and not r["paced"] for r in rows)),
        "other_feed_holds": int(sum(r.get("other", 0.0) for r in rows)),
        "latency_ms_median": float(np.median(lat)) if lat.size else float("nan"),
        "latency_ms_p99": p99,
        "latency_ms_max": float(lat.max()) if lat.size else float("nan"),
        "latency_ms_min": float(lat.min()) if lat.size else float("nan"),
        "detection_ms_median": float(np.median(det)) if det.size else float("nan"),
        "detection_ms_max": float(det.max()) if det.size else float("nan"),
        "commands_published": holds,
        "target_p99_ms": TARGET_P99_MS,
        "target_met": bool(
            lat.size >= min(30, len(rows))
            and not any("missed" in r for r in rows)
            and p99 < TARGET_P99_MS
        ),
    }
