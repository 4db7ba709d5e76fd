"""Two ``cutwatch worker`` processes on two shards of a real Mosquitto, one feeder
publishing four machines: one worker is SIGKILLed just after a checkpoint and restarted;
its machines publish again after the restart (how soon is a speed: printed here as
seconds_to_publish_after_restart, waited for up to 120 s; 10 s was asserted), resumed from
their checkpoints (the estimates' time and the segment identifier's inertia, damping and
Coulomb friction and the adaptive observer's inertia go on from where they were, not from
a new machine), while the other shard's machines never stop. (A broker-fed pipeline has
no flank-wear estimate: the wear model is the simulator's scenario; its ``VB_mm`` is null
in ``cutwatch serve`` too.)
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import paho.mqtt.client as mqtt
import pytest
from _broker import broker, free_port
from _proc import stop

from harness.shards import shard_of
from server.records.drive_wire import decode_estimates

pytestmark = pytest.mark.slow

MACHINES = ("mill-1", "m001", "m002", "m003")  # two on each shard of 2
#: a deadline for the restarted worker's first estimates, not a budget (that is a speed)
RESTART_DEADLINE_S = 120.0
PARAMS = ("J_L_seg", "B_L_seg", "F_CL_seg", "J_L_adaptive")


def _cutwatch(*args: str) -> list[str]:
    return [sys.executable, "-m", "server.cli.main", *args]


class Estimates:
    """Every estimates message of every machine, as (arrival wall time, message)."""

    def __init__(self, port: int) -> None:
        self.lock = threading.Lock()
        self.seen: dict[str, list[tuple[float, dict[str, Any]]]] = {}
        c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"test-est-{os.getpid()}")
        c.on_message = self._on
        c.connect("127.0.0.1", port)
        c.subscribe("cutwatch/+/estimates")
        c.loop_start()
        self.client = c

    def _on(self, _c: object, _u: object, msg: Any) -> None:
        d = decode_estimates(bytes(msg.payload))
        with self.lock:
            self.seen.setdefault(str(d["machine"]), []).append((time.time(), d))

    def of(self, machine: str, since: float = 0.0) -> list[dict[str, Any]]:
        with self.lock:
            return [d for w, d in self.seen.get(machine, []) if w >= since]

    def seen_before(self, machine: str, until: float) -> list[tuple[float, dict[str, Any]]]:
        with self.lock:
            return [(w, d) for w, d in self.seen.get(machine, []) if w < until]

    def close(self) -> None:
        self.client.loop_stop()
        self.client.disconnect()


def _wait(cond: Any, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if cond():
            return
        time.sleep(0.1)
    raise AssertionError(f"not within {timeout:g} s: {what}")


@pytest.fixture
def plant(tmp_path: Path) -> Iterator[dict[str, Any]]:
    log = tmp_path / "run.csv"
    subprocess.run(
        _cutwatch("simulate", "--out", str(log), "--seconds", "150"),
        check=True,
        capture_output=True,
    )
    with broker() as port:
        yield {"port": port, "log": log, "dir": tmp_path}


def _worker(shard: int, port: int, http: int, data: Path) -> subprocess.Popen[bytes]:
    return subprocess.Popen(
        _cutwatch("worker", "--broker", f"mqtt://127.0.0.1:{port}", "--shard", f"{shard}/2",
                  "--data-dir", str(data), "--port", str(http), "--checkpoint-s", "1"),
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip


def _ready(http: int) -> bool:
    try:
        return httpx.get(f"http://127.0.0.1:{http}/api/health", timeout=2).json()["status"] == "ok"
    except (httpx.HTTPError, ValueError):
        return False


def test_a_killed_worker_resumes_its_machines(plant: dict[str, Any]) -> None:
    port, d = plant["port"], plant["dir"]
    shards = {m: shard_of(m, 2) for m in MACHINES}
    assert sorted(shards.values()) == [0, 0, 1, 1], shards
    mine = [m for m in MACHINES if shards[m] == 0]
    others = [m for m in MACHINES if shards[m] == 1]
    http = [free_port(), free_port()]
    est = Estimates(port)
    workers = [_worker(i, port, http[i], d / f"w{i}") for i in (0, 1)]
    feeder = None
    try:
        _wait(lambda: all(_ready(h) for h in http), 120, "both workers ready")
        feeder = subprocess.Popen(
            _cutwatch("feed", str(plant["log"]), "--broker", f"mqtt://127.0.0.1:{port}",
                      "--machine", ",".join(MACHINES), "--quiet"),
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )  # fmt: skip

        def running(m: str) -> bool:  # identified for a while (reversals seen)
            e = est.of(m)
            return bool(e) and e[-1]["t"] > 15.0

        _wait(lambda: all(running(m) for m in MACHINES), 120, "every machine estimated")
        # each machine is on exactly one worker: the other shard's health does not list it
        h0 = httpx.get(f"http://127.0.0.1:{http[0]}/api/machines", timeout=5).json()
        assert sorted(r["machine"] for r in h0) == sorted(mine)
        # killed just after a periodic checkpoint (1 s) of each machine, seen on disk (was:
        # after a fixed 2.5 s, in which a loaded box's writer need not have written one)
        mark = time.time()
        state = [d / "w0" / "state" / f"{m}.npz" for m in mine]
        _wait(lambda: all(f.exists() and f.stat().st_mtime > mark for f in state), 60,
              f"a checkpoint of {mine} written")  # fmt: skip
        workers[0].send_signal(signal.SIGKILL)
        workers[0].wait(10)
        killed = time.time()
        before = {m: est.of(m)[-1] for m in mine}
        # the other shard goes on (polled until each of its machines published 10 more; was
        # counted after a fixed 3 s); the killed one's machines meanwhile publish nothing
        _wait(lambda: all(len(est.of(m, killed + 0.5)) >= 10 for m in others), 60,
              "the other shard publishes on")  # fmt: skip
        assert all(not est.of(m, killed + 0.5) for m in mine), "a killed worker published"
        workers[0] = _worker(0, port, http[0], d / "w0")
        restarted = time.time()
        _wait(lambda: all(est.of(m, restarted) for m in mine), RESTART_DEADLINE_S,
              f"{mine} publish again after the restart")  # fmt: skip
        back = {m: time.time() - restarted for m in mine}
        time.sleep(1.0)
        for m in mine:
            b, a = before[m], est.of(m, restarted)[0]
            assert a["health"]["resumed"] is True, a["health"]
            # time goes on from the checkpoint (<= 1 s + a block before the kill), not 0
            assert b["t"] - 2.0 < a["t"] < b["t"] + 1.0, (m, b["t"], a["t"])
            # the identified parameters carry on (a fresh pipeline starts from the nominal
            # values and the first reversals); they move a little over the samples since.
            # The state resumed is the checkpoint's (<= 1 s before the kill), so the value
            # to compare with is one the worker published near the resumed time, not
            # necessarily its last: a reversal segment finished between the checkpoint and
            # the kill moves J_L_seg by up to ~10 % (seen once in a full-suite run)
            near = [d for w, d in est.seen_before(m, killed) if abs(d["t"] - a["t"]) <= 1.5]
            assert near, (m, a["t"])
            for k in PARAMS:
                va = a["params"][k]
                vbs = [d["params"][k] for d in near]
                assert min(abs(va - vb) / abs(vb) for vb in vbs) < 0.03, (m, k, vbs, va)
        after = {m: est.of(m, restarted)[0] for m in mine}

        def row(d: dict[str, Any]) -> list[float]:
            return [d["t"], *(d["params"][k] for k in PARAMS)]

        print(json.dumps({
            "seconds_to_publish_after_restart": back,
            "before": {m: row(before[m]) for m in mine},
            "after": {m: row(after[m]) for m in mine},
        }))  # fmt: skip
    finally:
        est.close()
        if feeder is not None:
            stop(feeder)
        for w in workers:
            stop(w)
