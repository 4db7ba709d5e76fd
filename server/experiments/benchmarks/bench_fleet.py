"""A fleet through one broker: N machines, each a real ``cutwatch serve --source mqtt``
fed by a real ``cutwatch feed``, all publishing estimates to one Mosquitto, watched by
one ``cutwatch fleet`` page.

Measured over a window of ``SECONDS`` (every process is a real subprocess; CPU from
``/proc/<pid>/stat``, in % of one core):

- the broker's CPU, the fleet page's CPU, the services' and the feeders' CPU (sums);
- the end-to-end latency from a drive block's publish (its ``wall`` stamp, set by the
  feeder) to the estimate that includes it arriving on the fleet page's WebSocket (the
  same host clock): p50, p99, max over every row update of every machine;
- one machine's feeder killed mid-run and restarted: the seconds until its row shows
  ``stale`` and, after the restart, until it shows ``ok`` again.

With ``workers`` > 0 (``cutwatch bench fleet --machines 100 --workers 2``) the plant
mode instead: the machines are spread over that many ``cutwatch worker --shard I/W``
processes, and ONE ``cutwatch feed`` publishes every machine (as an edge gateway of a
cell does; they share this box). Measured over the steady window (the first 40 % of
``seconds``): the rows ok, the drive-to-page latency, the CPU of the workers (sum, and
per machine), the feeder, the broker and the fleet page, the workers' memory (RSS; per
machine: the sum over the workers / N, and the marginal one: minus the workers' RSS when
ready and idle); then worker 0 is SIGKILLed and restarted at once (a supervisor's
``Restart=always``): the seconds from its restart until every one of its machines has
published again, and whether they resumed from their checkpoints.

Needs Debian's ``mosquitto`` (``make system-deps``). Linux only (``/proc``). Heavy: N
service processes (~250 MB each) — this is a benchmark, not a test.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import httpx
import numpy as np

from server.experiments.benchmarks import Figures
from server.experiments.benchmarks._local import free_port, mosquitto

MACHINES = 20
SECONDS = 60.0
STALE_AFTER = 3.0
PUBLISH_HZ = 10.0
TICK = os.sysconf("SC_CLK_TCK")


def _cpu(pid: int) -> float:
    try:
        f = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(f[11]) + int(f[12])) / TICK


def _cutwatch(*args: str) -> list[str]:
    return [sys.executable, "-m", "server.cli.main", *args]


def _wait_http(url: str, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        with contextlib.suppress(httpx.HTTPError):
            if httpx.get(url, timeout=1).status_code == 200:
                return
        time.sleep(0.2)
    raise RuntimeError(f"{url} did not answer within {timeout:g} s")


def _stop(procs: list[subprocess.Popen[Any]]) -> None:
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
    for p in procs:
        try:
            p.wait(10)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(5)


def _start_services(
    names: list[str],
    url: str,
    env: dict[str, str],
    services: list[subprocess.Popen[bytes]],
    progress: bool,
) -> list[int]:
    """One ``cutwatch serve --source mqtt`` per machine name, each waited for; appended to
    ``services`` as they start (so the caller stops them whatever happens); their ports."""
    ports: list[int] = []
    for name in names:
        port = free_port()
        ports.append(port)
        services.append(
            subprocess.Popen(
                _cutwatch("serve", "--port", str(port), "--no-viser", "--source", "mqtt",
                          "--broker", url, "--machine", name,
                          "--publish-hz", str(PUBLISH_HZ)),
                # each its own data directory (its checkpoint; not the caller's ./data)
                env={**env, "CUTWATCH_PUBLIC_URL": f"http://127.0.0.1:{port}/",
                     "CUTWATCH_DATA_DIR": str(Path(env["CUTWATCH_BENCH_WORK"]) / name)},
                stdout=subprocess.DEVNULL,
            )
        )  # fmt: skip
        _wait_http(f"http://127.0.0.1:{port}/api/health", 120)
        if progress:
            print(f"  service {name} up", file=sys.stderr)
    return ports


def _wait_receiving(ports: list[int]) -> None:
    """Until every service receives its feed (every pipeline built on its meta)."""
    deadline = time.monotonic() + 180
    for port in ports:
        while True:
            h = httpx.get(f"http://127.0.0.1:{port}/api/health", timeout=5).json()
            if h["feed"]["state"] == "receiving" and h["feed"]["blocks"] > 20:
                break
            if time.monotonic() > deadline:
                raise RuntimeError(f"service :{port} never received: {h['feed']}")
            time.sleep(0.5)


def _watch(
    fport: int,
    seconds: float,
    victim: str,
    feeders: dict[str, subprocess.Popen[bytes]],
    feed: Callable[[str], subprocess.Popen[bytes]],
) -> tuple[list[float], tuple[float | None, float | None, float | None, float | None]]:
    """Watch the fleet page's stream for ``seconds``: the drive-to-page latencies, and the
    victim's feeder killed at 40 % and restarted once its row is stale; returns the
    latencies and the monotonic times killed, restarted, stale, recovered (None: never)."""
    from websockets.sync.client import connect

    t0 = time.monotonic()
    lat: list[float] = []
    killed_at = restarted_at = stale_at = recovered_at = None
    with connect(f"ws://127.0.0.1:{fport}/ws") as ws:
        while time.monotonic() - t0 < seconds:
            msg = json.loads(ws.recv(timeout=10))
            now = time.time()
            rows = msg["rows"] if "rows" in msg else [msg]
            for r in rows:
                if "rows" not in msg and r.get("drive_wall") is not None:
                    lat.append(now - float(r["drive_wall"]))
                if r["machine"] == victim and killed_at is not None:
                    if stale_at is None and r["status"] == "stale":
                        stale_at = time.monotonic()
                    if restarted_at is not None and stale_at is not None:
                        if recovered_at is None and r["status"] == "ok":
                            recovered_at = time.monotonic()
            el = time.monotonic() - t0
            if killed_at is None and el > seconds * 0.4:
                feeders[victim].kill()
                feeders[victim].wait(5)
                killed_at = time.monotonic()
            if restarted_at is None and stale_at is not None:
                feeders[victim] = feed(victim)
                restarted_at = time.monotonic()
    return lat, (killed_at, restarted_at, stale_at, recovered_at)


def _run(machines: int, seconds: float, progress: bool) -> Figures:
    work = Path(tempfile.mkdtemp(prefix="cutwatch-bench-fleet-"))
    log = work / "drive.csv"
    subprocess.run(
        _cutwatch("simulate", "--out", str(log), "--seconds", str(seconds + 60)),
        check=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    bport, fport = free_port(), free_port()
    url = f"mqtt://127.0.0.1:{bport}"
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "CUTWATCH_BENCH_WORK": str(work)}
    services: list[subprocess.Popen[bytes]] = []
    feeders: dict[str, subprocess.Popen[bytes]] = {}
    fleet = None
    out: Figures = {
        "configuration": (
            f"{machines} x (cutwatch feed -> mosquitto -> cutwatch serve --source mqtt "
            f"--publish-hz {PUBLISH_HZ:g}) -> cutwatch fleet; 2-core machine"
        ),
        "machines": machines,
    }
    with mosquitto(bport) as broker:
        try:
            fleet = subprocess.Popen(
                _cutwatch("fleet", "--broker", url, "--port", str(fport),
                          "--stale-after", str(STALE_AFTER)),
                env=env, stdout=subprocess.DEVNULL,
            )  # fmt: skip
            names = [f"m{k:02d}" for k in range(machines)]
            ports = _start_services(names, url, env, services, progress)
            _wait_http(f"http://127.0.0.1:{fport}/api/health", 60)

            def feed(name: str) -> subprocess.Popen[bytes]:
                return subprocess.Popen(
                    _cutwatch("feed", str(log), "--broker", url, "--machine", name, "--quiet"),
                    env=env,
                )

            for name in names:
                feeders[name] = feed(name)
            _wait_receiving(ports)
            time.sleep(2 * STALE_AFTER)  # the fleet page has seen every machine
            hs = [httpx.get(f"http://127.0.0.1:{p}/api/health", timeout=5).json() for p in ports]
            out["services.publishing"] = sum(
                bool(h.get("estimates_out", {}).get("published")) for h in hs
            )
            fh = httpx.get(f"http://127.0.0.1:{fport}/api/health", timeout=5).json()
            out["fleet.connected_at_start"] = bool(fh.get("connected"))
            out["fleet.machines_at_start"] = int(fh.get("machines", 0))
            pids = {
                "broker": [broker.pid],
                "fleet": [fleet.pid],
                "services": [p.pid for p in services],
                "feeders": [p.pid for p in feeders.values()],
            }
            victim = names[0]
            pids["feeders"] = [p.pid for n, p in feeders.items() if n != victim]
            cpu0 = {k: sum(_cpu(p) for p in v) for k, v in pids.items()}
            t0 = time.monotonic()
            lat, (killed_at, restarted_at, stale_at, recovered_at) = _watch(
                fport, seconds, victim, feeders, feed
            )
            wall = time.monotonic() - t0
            cpu1 = {k: sum(_cpu(p) for p in v) for k, v in pids.items()}
            for k in pids:
                out[f"cpu_pct_one_core.{k}"] = 100.0 * (cpu1[k] - cpu0[k]) / wall
            # the victim's feeder was replaced: the others' mean stands for it
            out["cpu_pct_one_core.feeders"] = (
                float(out["cpu_pct_one_core.feeders"]) * machines / max(machines - 1, 1)  # type: ignore[arg-type]
            )
            a = np.asarray(lat)
            out["latency_ms.p50"] = 1e3 * float(np.percentile(a, 50)) if a.size else float("nan")
            out["latency_ms.p99"] = 1e3 * float(np.percentile(a, 99)) if a.size else float("nan")
            out["latency_ms.max"] = 1e3 * float(a.max()) if a.size else float("nan")
            out["latency.samples"] = int(a.size)
            out["killed.seconds_to_stale"] = (
                stale_at - killed_at if stale_at and killed_at else float("nan")
            )
            out["restarted.seconds_to_ok"] = (
                recovered_at - restarted_at if recovered_at and restarted_at else float("nan")
            )
            rows = httpx.get(f"http://127.0.0.1:{fport}/api/fleet", timeout=5).json()
            out["fleet.rows"] = len(rows)
            out["fleet.ok_at_end"] = sum(r["status"] == "ok" for r in rows)
        finally:
            _stop(list(feeders.values()))
            _stop(services)
            if fleet is not None:
                _stop([fleet])
            shutil.rmtree(work, ignore_errors=True)
    return out


def measure(
    *,
    repeats: int,
    quick: bool,
    machines: int | None = None,
    workers: int = 0,
    seconds: float | None = None,
    soak: bool = False,
    centres: bool = False,
    feed_speed: float = 1.0,
) -> Figures:
    """One run (the fleet is the repetition: every machine's latency counts). ``workers``
    0: one ``cutwatch serve`` per machine (today's mode); > 0: the plant mode
    (``centres``: of machining centres at 500 Hz replaying a recorded trace, fed at
    ``feed_speed`` log seconds per wall second)."""
    n = machines if machines is not None else (4 if quick else MACHINES)
    secs = seconds if seconds is not None else (20.0 if quick else SECONDS)
    if workers > 0:
        from server.experiments.benchmarks._fleet_plant import run_plant

        return run_plant(n, workers, secs, progress=not quick, soak=soak, centres=centres,
                         feed_speed=feed_speed)  # fmt: skip
    return _run(n, secs, progress=not quick)
