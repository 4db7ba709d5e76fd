"""One OPC UA source under load: the values per second it takes with the loop healthy, and
the latency from a node's change to the dashboard (issue 33, item 6).

What runs, each real: a load server (:mod:`server.experiments.benchmarks._opcua_load`, a
child process: ``AXES`` rigid axes of six signals and a spindle, every node written each
sampling interval with its source timestamp, Aes256_Sha256_RsaPss SignAndEncrypt) and
``cutwatch serve --source opcua`` (a child process, the load's node map, the server's
certificate trusted), with one WebSocket client reading every frame (a dashboard open).
For each sampling interval of :data:`SAMPLE_TIMES` (values per second = nodes / interval)
the service runs ``seconds`` (``--opcua-publishing`` the sampling interval, so the
asyncua server, which revises the sampling interval to the publishing interval, keeps
it); read from ``/api/health`` at the start and the end of the window: the samples the
source received per second, lost / late / merged samples in the window, the loop's p99
lag and the samples still buffered. The run is *healthy* when nothing was lost, late or
merged, the p99 lag is below :data:`HEALTHY_LAG_MS` and less than a second of samples waits.

The latency: the probe node ``S.speed`` holds its own source timestamp (mod 1000 s); each
frame's newest ``spindle_speed`` (the spindle part's channel of that node) at the
frame's arrival (this process's clock, the same host) is one latency: the
subscription's publishing interval, the grid's watermark (a publishing and a sampling
interval), the loop's block and the frame period. Median and
p95 over the frames of the run.

Both processes, the load server's writes and the service, share this machine's cores:
a faster server would leave the service more. The asyncua maintainers advise splitting
past ~3,000 items at 1 s per connection; docs/opcua.md says where one source lies.
"""

from __future__ import annotations

import contextlib
import json
import os
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
from server.experiments.benchmarks._local import free_port
from server.experiments.benchmarks._opcua_load import ROLES, node_map

AXES = 16
SAMPLE_TIMES = (0.1, 0.05, 0.02, 0.01)
HEALTHY_LAG_MS = 250.0


@contextlib.contextmanager
def _child(cmd: list[str], ready: str, log: Path, env: dict[str, str] | None = None,
           timeout: float = 120.0) -> Iterator[subprocess.Popen[str]]:  # fmt: skip
    out = log.open("w")
    proc = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT, text=True,
                            env={**os.environ, **(env or {})})  # fmt: skip
    try:
        deadline = time.monotonic() + timeout
        while ready not in log.read_text():
            if proc.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"{cmd[2:4]} did not start: {log.read_text()[-800:]}")
            time.sleep(0.2)
        yield proc
    finally:
        proc.terminate()
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
        out.close()


def _dashboard(url: str, stop: threading.Event, lat: list[float]) -> threading.Thread:
    """A WebSocket client reading every frame; the probe's latency of each."""
    from websockets.sync.client import connect

    def read() -> None:
        with connect(url, max_size=None) as ws:
            while not stop.is_set():
                try:
                    msg = json.loads(ws.recv(timeout=0.5))
                except TimeoutError:
                    continue
                w = time.time()
                vals = [v for v in (msg.get("ch") or {}).get("spindle_speed", []) if v is not None]
                if msg.get("type") == "data" and vals:
                    lat.append((w - vals[-1]) % 1000.0)

    th = threading.Thread(target=read, name="bench-opcua-dashboard", daemon=True)
    th.start()
    return th


def _one(d: Path, sample_time: float, seconds: float) -> dict[str, float]:
    sport, hport = free_port(), free_port()
    d.mkdir(parents=True, exist_ok=True)
    mp = d / f"map-{sample_time:g}.json"
    mp.write_text(json.dumps(node_map(AXES, sample_time)))
    load = [sys.executable, "-m", "server.experiments.benchmarks._opcua_load", "--port",
            str(sport), "--axes", str(AXES), "--sample-time", str(sample_time),
            "--cert-dir", str(d / "load")]  # fmt: skip
    with _child(load, "ready", d / "load.out"):
        serve = [sys.executable, "-m", "server.cli.main", "serve", "--port", str(hport),
                 "--no-viser", "--source", "opcua", "--opcua", f"opc.tcp://127.0.0.1:{sport}/load",
                 "--nodes", str(mp), "--opcua-trust", str(d / "load" / "server-cert.der"),
                 "--data-dir", str(d / "data"), "--opcua-publishing", str(sample_time)]  # fmt: skip
        env = {"CUTWATCH_CHECKPOINT_S": "0"}
        with _child(serve, "cutwatch dashboard", d / "serve.out", env):
            base = f"http://127.0.0.1:{hport}"
            deadline = time.monotonic() + 60
            h: dict[str, Any] = {}
            while time.monotonic() < deadline:
                with contextlib.suppress(httpx.HTTPError):
                    h = httpx.get(f"{base}/api/health", timeout=5).json()
                    if h.get("opcua", {}).get("taken", 0) > 0:
                        break
                time.sleep(0.25)
            stop, lat = threading.Event(), list[float]()
            th = _dashboard(f"ws://127.0.0.1:{hport}/ws", stop, lat)
            time.sleep(2.0)  # the pipeline built at the revised rate, the dashboard on
            h0 = httpx.get(f"{base}/api/health", timeout=5).json()["opcua"]
            w0 = time.monotonic()
            lat.clear()
            time.sleep(seconds)
            h1 = httpx.get(f"{base}/api/health", timeout=5).json()
            w1 = time.monotonic()
            stop.set()
            th.join(5)
    o = h1["opcua"]
    nodes = AXES * len(ROLES) + 2
    rate = (o["samples"] - h0["samples"]) / (w1 - w0)
    lost, late, merged = (o[k] - h0[k] for k in ("lost", "late", "merged"))
    healthy = (
        lost == 0 and late == 0 and merged == 0
        and h1["lag_p99_ms"] < HEALTHY_LAG_MS and o["buffered"] * o["sample_time"] < 1.0
    )  # fmt: skip
    arr = np.asarray(lat) if lat else np.asarray([np.nan])
    return {
        "nodes": float(nodes),
        "offered_values_per_s": nodes / sample_time,
        "values_per_s": float(rate),
        "lost": float(lost),
        "late": float(late),
        "merged": float(merged),
        "late_before_window": float(h0["late"]),
        "lag_p99_ms": float(h1["lag_p99_ms"]),
        "buffered_s": float(o["buffered"] * o["sample_time"]),
        "latency_ms.median": 1e3 * float(np.median(arr)),
        "latency_ms.p95": 1e3 * float(np.percentile(arr, 95)),
        "healthy": float(healthy),
    }


def measure(*, repeats: int, quick: bool) -> Figures:
    seconds = 8.0 if quick else 30.0
    times = SAMPLE_TIMES[:2] if quick else SAMPLE_TIMES
    out: Figures = {
        "configuration": f"one opcua source, {AXES} rigid axes x {len(ROLES)} signals + 2 "
        f"spindle nodes, Aes256_Sha256_RsaPss SignAndEncrypt, load server and service on "
        f"this machine, {seconds:g} s per sampling interval, one dashboard client"
    }
    best = 0.0
    with tempfile.TemporaryDirectory(prefix="cutwatch-bench-opcua-") as tmp:
        for ts in times:
            rows = [_one(Path(tmp) / f"{ts:g}-{i}", ts, seconds) for i in range(max(1, repeats))]
            label = f"{1 / ts:g}Hz"
            for k in rows[0]:
                out[f"{label}.{k}"] = float(np.median([r[k] for r in rows]))
            if all(r["healthy"] for r in rows):
                best = max(best, float(np.median([r["values_per_s"] for r in rows])))
    out["healthy_values_per_s.max"] = best
    return out
