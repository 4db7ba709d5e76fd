"""The live service under load: the real ``cutwatch serve`` and real WebSocket clients.

Starts the service as a subprocess at 1x real time, connects ``CLIENTS`` WebSocket
clients that read every frame, and measures over ``repeats`` windows:

- the service's CPU use in % of one core (``/proc/<pid>/stat``, median over windows),
- loop-to-client frame latency (receipt time minus the frame's ``wall`` stamp, same
  host clock; p50 and p99 over every frame of every client),
- the service's resident memory and its slope (least squares over 1 s samples),
- the loop's own lag p99 and real-time factor (from ``/metrics``).

Then one more client connects that never reads (tiny receive buffer), and the same is
measured for the others; the service's memory growth during that phase is reported.
Linux only (``/proc``).
"""

from __future__ import annotations

import asyncio
import json
import os
import socket
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np

CLIENTS = 10
TICK = os.sysconf("SC_CLK_TCK")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICK  # utime, stime


def _rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def _metrics(base: str) -> dict[str, float]:
    text = httpx.get(f"{base}/metrics", timeout=5).text
    return {
        ln.split()[0]: float(ln.split()[1])
        for ln in text.splitlines()
        if ln and not ln.startswith("#")
    }


async def _reader(url: str, lat: list[float], stop: asyncio.Event) -> None:
    from websockets.asyncio.client import connect

    async with connect(url, max_size=None) as ws:
        await ws.recv()  # hello
        while not stop.is_set():
            try:
                msg = await asyncio.wait_for(ws.recv(), 1.0)
            except TimeoutError:
                continue
            now = time.time()
            frame = json.loads(msg)
            lat.append(now - frame["wall"])


async def _session(
    base: str, ws_url: str, pid: int, windows: int, window_s: float, slow_s: float
) -> dict[str, Any]:
    lat: list[float] = []
    stop = asyncio.Event()
    tasks = [asyncio.create_task(_reader(ws_url, lat, stop)) for _ in range(CLIENTS)]
    await asyncio.sleep(2.0)  # connect and settle
    lat.clear()
    cpu: list[float] = []
    rss_t: list[float] = []
    rss: list[float] = []
    t_start = time.monotonic()
    for _ in range(windows):
        c0, w0 = _cpu_seconds(pid), time.monotonic()
        end = w0 + window_s
        while time.monotonic() < end:
            rss_t.append(time.monotonic() - t_start)
            rss.append(_rss_mb(pid))
            await asyncio.sleep(1.0)
        cpu.append(100.0 * (_cpu_seconds(pid) - c0) / (time.monotonic() - w0))
    m = _metrics(base)
    out: dict[str, Any] = {
        "clients": CLIENTS,
        "window_s": window_s,
        "windows": windows,
        "cpu_percent_one_core": statistics.median(cpu),
        "cpu_percent_max_window": max(cpu),
        "frame_latency_p50_ms": 1e3 * float(np.percentile(lat, 50)),
        "frame_latency_p99_ms": 1e3 * float(np.percentile(lat, 99)),
        "frames_received": len(lat),
        "rss_mb": rss[-1],
        "rss_slope_mb_per_min": 60.0 * float(np.polyfit(rss_t, rss, 1)[0]),
        "loop_lag_p99_ms": 1e3 * m["cutwatch_loop_lag_p99_seconds"],
        "live_realtime_factor": m["cutwatch_realtime_factor"],
        "dropped_frames": m["cutwatch_ws_dropped_frames_total"],
    }
    # one client that never reads
    host, port = base.removeprefix("http://").split(":")
    raw = socket.create_connection((host, int(port)))
    raw.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    from websockets.sync.client import connect as sync_connect

    slow = await asyncio.to_thread(
        sync_connect, ws_url, sock=raw, max_queue=1, ping_interval=None, close_timeout=1
    )
    lat.clear()
    rss0 = _rss_mb(pid)
    peak = rss0
    end = time.monotonic() + slow_s
    while time.monotonic() < end:
        await asyncio.sleep(1.0)
        peak = max(peak, _rss_mb(pid))
    m2 = _metrics(base)
    out.update(
        {
            "slow_client_s": slow_s,
            "slow_client_rss_growth_mb": peak - rss0,
            "slow_client_dropped_frames": m2["cutwatch_ws_dropped_frames_total"]
            - m["cutwatch_ws_dropped_frames_total"],
            "slow_phase_frame_latency_p99_ms": 1e3 * float(np.percentile(lat, 99)),
            "slow_phase_frames_received": len(lat),
        }
    )
    stop.set()
    await asyncio.gather(*tasks, return_exceptions=True)
    slow.close()
    raw.close()
    return out


def measure(*, repeats: int, quick: bool) -> dict[str, object]:
    """Run the service with 10 clients for ``repeats`` windows (10 s quick, 60 s full)."""
    port, viser_port = _free_port(), _free_port()
    env = dict(os.environ, CUTWATCH_PORT=str(port), CUTWATCH_VISER_PORT=str(viser_port))
    proc = subprocess.Popen(
        [sys.executable, "-m", "server.cli.main", "serve"],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 60
        while True:
            if proc.poll() is not None:
                err = proc.stderr.read().decode() if proc.stderr else ""
                raise RuntimeError(f"cutwatch serve exited: {err[-500:]}")
            try:
                if httpx.get(f"{base}/api/health", timeout=1).json()["sim_t"] > 1.0:
                    break
            except (httpx.HTTPError, KeyError):
                pass
            if time.monotonic() > deadline:
                raise RuntimeError("cutwatch serve did not come up in 60 s")
            time.sleep(0.2)
        window = 10.0 if quick else 60.0
        res = asyncio.run(
            _session(
                base,
                f"ws://127.0.0.1:{port}/ws",
                proc.pid,
                max(1, repeats),
                window,
                10.0 if quick else 30.0,
            )
        )
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
    return res
