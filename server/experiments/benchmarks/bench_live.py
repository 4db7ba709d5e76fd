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

:func:`soak` is the long form (``cutwatch bench live --duration 1800``, or
``python -m server.experiments.benchmarks.bench_live --duration 1800 --out soak.json``):
one run of the service with the 10 clients for ``duration_s``, sampling its resident
memory every few seconds and its CPU per minute, counting every frame each client
receives, the frame counter's gaps and the drops the service reports; the memory
slope is fitted after a warm-up (the first ``warmup_s``), so start-up allocation (numba,
caches filling to their bound) does not count as growth.
"""

from __future__ import annotations

import asyncio
import json
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import numpy as np

from server.experiments.benchmarks import Figures
from server.experiments.benchmarks._local import free_port

CLIENTS = 10
TICK = os.sysconf("SC_CLK_TCK")


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


def _start_service() -> tuple[subprocess.Popen[bytes], str]:
    """``cutwatch serve`` on free loopback ports, once it has simulated 1 s."""
    port, viser_port = free_port(), free_port()
    env = dict(os.environ, CUTWATCH_PORT=str(port), CUTWATCH_VISER_PORT=str(viser_port))
    # the child's log goes to a file: an unread pipe fills over a long run and blocks it
    log = tempfile.TemporaryFile()
    proc = subprocess.Popen(
        # the seeds' scenario, as measured before the centre became the default (issue 31)
        [sys.executable, "-m", "server.cli.main", "serve", "--scenario", "default"],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=log,
    )
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 60
        while True:
            if proc.poll() is not None:
                log.seek(0)
                err = log.read().decode(errors="replace")
                raise RuntimeError(f"cutwatch serve exited: {err[-500:]}")
            try:
                if httpx.get(f"{base}/api/health", timeout=1).json()["sim_t"] > 1.0:
                    break
            except (httpx.HTTPError, KeyError):
                pass
            if time.monotonic() > deadline:
                raise RuntimeError("cutwatch serve did not come up in 60 s")
            time.sleep(0.2)
    except BaseException:
        _stop(proc)
        raise
    return proc, base


def _stop(proc: subprocess.Popen[bytes]) -> None:
    proc.terminate()
    try:
        proc.wait(10)
    except subprocess.TimeoutExpired:
        proc.kill()


def measure(*, repeats: int, quick: bool) -> Figures:
    """Run the service with 10 clients for ``repeats`` windows (10 s quick, 60 s full)."""
    proc, base = _start_service()
    port = int(base.rsplit(":", 1)[1])
    try:
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
        _stop(proc)
    return res


@dataclass
class _Client:
    """What one soak client saw: frames, the frame counter's gaps, reported drops."""

    frames: int = 0
    seq_gaps: int = 0  # frames missing between consecutive seq numbers
    dropped_reported: int = 0  # sum of the frames' ``dropped`` fields
    hellos: int = 0
    last_seq: int | None = None
    lat: list[float] = field(default_factory=list)
    error: str = ""


async def _soak_reader(url: str, c: _Client, stop: asyncio.Event) -> None:
    from websockets.asyncio.client import connect

    try:
        async with connect(url, max_size=None) as ws:
            while not stop.is_set():
                try:
                    msg = await asyncio.wait_for(ws.recv(), 1.0)
                except TimeoutError:
                    continue
                now = time.time()
                frame = json.loads(msg)
                if frame.get("type") != "data":
                    c.hellos += frame.get("type") == "hello"
                    continue
                c.frames += 1
                c.dropped_reported += int(frame.get("dropped", 0))
                seq = int(frame["seq"])
                if c.last_seq is not None and seq > c.last_seq + 1:
                    c.seq_gaps += seq - c.last_seq - 1
                c.last_seq = seq
                c.lat.append(now - frame["wall"])
    except Exception as exc:  # a client that fails is reported, not hidden
        c.error = f"{type(exc).__name__}: {exc}"


async def _soak_session(
    base: str, pid: int, duration_s: float, warmup_s: float, sample_s: float
) -> dict[str, Any]:
    ws_url = base.replace("http://", "ws://") + "/ws"
    stop = asyncio.Event()
    clients = [_Client() for _ in range(CLIENTS)]
    tasks = [asyncio.create_task(_soak_reader(ws_url, c, stop)) for c in clients]
    await asyncio.sleep(2.0)
    m0 = _metrics(base)
    t0 = time.monotonic()
    c0 = _cpu_seconds(pid)
    series: list[dict[str, float]] = []
    cpu_min: list[float] = []
    last_c, last_t = c0, t0
    while (now := time.monotonic()) - t0 < duration_s:
        series.append({"t_s": now - t0, "rss_mb": _rss_mb(pid), "cpu_s": _cpu_seconds(pid)})
        if now - last_t >= 60.0:
            c = series[-1]["cpu_s"]
            cpu_min.append(100.0 * (c - last_c) / (now - last_t))
            last_c, last_t = c, now
        await asyncio.sleep(sample_s)
    wall = time.monotonic() - t0
    cpu_total = 100.0 * (_cpu_seconds(pid) - c0) / wall
    m1 = _metrics(base)
    stop.set()
    await asyncio.gather(*tasks, return_exceptions=True)
    return _soak_summary(clients, series, cpu_min, cpu_total, m0, m1, wall, warmup_s)


def _soak_summary(
    clients: list[_Client],
    series: list[dict[str, float]],
    cpu_min: list[float],
    cpu_total: float,
    m0: dict[str, float],
    m1: dict[str, float],
    wall: float,
    warmup_s: float,
) -> dict[str, Any]:
    t = np.array([s["t_s"] for s in series])
    rss = np.array([s["rss_mb"] for s in series])
    after = t >= min(warmup_s, 0.5 * wall)
    lat = np.concatenate([np.asarray(c.lat) for c in clients]) if clients else np.zeros(1)
    published = m1["cutwatch_frames_total"] - m0["cutwatch_frames_total"]
    return {
        "clients": CLIENTS,
        "duration_s": wall,
        "warmup_s": warmup_s,
        "cpu_percent_one_core": cpu_total,
        "cpu_percent_per_minute_median": float(np.median(cpu_min)) if cpu_min else cpu_total,
        "cpu_percent_per_minute_max": max(cpu_min) if cpu_min else cpu_total,
        "rss_mb_start": float(rss[0]),
        "rss_mb_after_warmup": float(rss[after][0]),
        "rss_mb_end": float(rss[-1]),
        "rss_mb_max": float(rss.max()),
        "rss_slope_mb_per_hour_after_warmup": 3600.0
        * float(np.polyfit(t[after], rss[after], 1)[0]),
        "frames_published": published,
        "frames_per_s": published / wall,
        "frames_received_per_client_min": min(c.frames for c in clients),
        "frames_received_per_client_max": max(c.frames for c in clients),
        "seq_gaps_total": sum(c.seq_gaps for c in clients),
        "dropped_reported_to_clients": sum(c.dropped_reported for c in clients),
        "dropped_frames_service": m1["cutwatch_ws_dropped_frames_total"]
        - m0["cutwatch_ws_dropped_frames_total"],
        "loop_stalls": m1.get("cutwatch_loop_stalls_total", 0.0)
        - m0.get("cutwatch_loop_stalls_total", 0.0),
        "frame_latency_p50_ms": 1e3 * float(np.percentile(lat, 50)),
        "frame_latency_p99_ms": 1e3 * float(np.percentile(lat, 99)),
        "frame_latency_max_ms": 1e3 * float(lat.max()),
        "loop_lag_p99_ms_end": 1e3 * m1["cutwatch_loop_lag_p99_seconds"],
        "live_realtime_factor_end": m1["cutwatch_realtime_factor"],
        "client_errors": [c.error for c in clients if c.error],
        "series": series,
    }


def soak(*, duration_s: float, warmup_s: float = 300.0, sample_s: float = 5.0) -> dict[str, Any]:
    """One long run of the service with 10 clients: memory and CPU over time, drops."""
    proc, base = _start_service()
    try:
        return asyncio.run(_soak_session(base, proc.pid, duration_s, warmup_s, sample_s))
    finally:
        _stop(proc)


def main(argv: list[str] | None = None) -> int:
    """``python -m server.experiments.benchmarks.bench_live --duration S [--out F]``."""
    import argparse

    ap = argparse.ArgumentParser(description="soak the live service with 10 clients")
    ap.add_argument("--duration", type=float, required=True, help="seconds of soak")
    ap.add_argument("--warmup", type=float, default=300.0, help="seconds before the slope")
    ap.add_argument("--sample", type=float, default=5.0, help="seconds between samples")
    ap.add_argument("--out", type=Path, help="write the JSON (with the series) here")
    a = ap.parse_args(argv)
    res = soak(duration_s=a.duration, warmup_s=a.warmup, sample_s=a.sample)
    text = json.dumps(res, indent=2)
    if a.out:
        a.out.write_text(text)
    print(json.dumps({k: v for k, v in res.items() if k != "series"}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
