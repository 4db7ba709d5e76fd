"""The live loop's lag while a large log is uploaded: the real ``cutwatch serve``, real HTTP.

Starts the service as a subprocess at 1x real time (the seeds' stage scenario, a data
directory of its own) and, ``repeats`` times, side by side in one run:

- an idle window: the loop's lag (``/api/health``'s ``lag_ms``, the lateness of the last
  block) sampled every 30 ms for ``IDLE_S`` seconds, nothing else asked of the service;
- an upload: a valid rigid CSV log of ``MB`` megabytes (20 with ``--quick``) posted to
  ``/api/uploads`` (its sidecar first), the lag sampled the same way until the answer (the
  body streamed to the quarantine, then checked in a child process), with the time to the
  answer and the service's peak resident memory over the upload.

Reports the medians over the repeats of the p99 and max lag in each phase, their ratio
(upload / idle: what the upload adds, read on a loaded machine too), the upload's seconds
and MB/s and the memory's growth. The lag was a test's threshold (p99 < 50 ms during an
80 MB upload) until a loaded CI box failed it for load alone; the test now judges what
cannot race (tests/service/test_security.py) and the figure is measured here.
Linux only (``/proc``).
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx
import numpy as np

from server.experiments.benchmarks import Figures
from server.experiments.benchmarks._local import free_port

#: the upload's size [MB] (``quick``: 20)
MB = 80.0
#: the idle window measured before each upload [s] (``quick``: 3)
IDLE_S = 10.0
#: the lag's sampling period [s]
SAMPLE_S = 0.03
SIDECAR = {"sample_time": 0.001, "units": {"effort": "N m", "position": "rad"}, "kind": "rigid"}


def rigid_log(path: Path, mb: float) -> int:
    """A valid rigid log of about ``mb`` MB (t, tau_m, q_m at 1 kHz); its rows."""
    n = int(mb * 1e6 / 39.5)  # 39.5 bytes per row at these formats
    t = np.arange(n) * 1e-3
    rng = np.random.default_rng(7)
    cols = np.column_stack([t, np.sin(t) + 0.01 * rng.standard_normal(n), np.cos(t)])
    with path.open("w") as fh:
        fh.write("t,tau_m,q_m\n")
        np.savetxt(fh, cols, fmt=["%.3f", "%.12f", "%.12f"], delimiter=",")
    return n


def _peak_kb(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1])
    return 0


def _lags_while(c: httpx.Client, busy: threading.Thread | None, seconds: float) -> list[float]:
    """The loop's lag [ms] sampled every SAMPLE_S while ``busy`` runs (or ``seconds``);
    at least one sample (taken at once, even if ``busy`` has already ended)."""
    lags: list[float] = []
    end = time.monotonic() + seconds
    while True:
        lags.append(float(c.get("/api/health").json()["lag_ms"]))
        if not (busy.is_alive() if busy is not None else time.monotonic() < end):
            return lags
        time.sleep(SAMPLE_S)


def _one(c: httpx.Client, pid: int, log: Path, i: int, idle_s: float) -> dict[str, float]:
    idle = _lags_while(c, None, idle_s)
    name = f"big-{i}"
    r = c.post("/api/uploads", params={"name": f"{name}.json"}, content=json.dumps(SIDECAR))
    r.raise_for_status()
    Path(f"/proc/{pid}/clear_refs").write_text("5")  # the peak from here
    rss0 = _peak_kb(pid)
    answer: dict[str, httpx.Response] = {}
    failed: list[BaseException] = []

    def send() -> None:  # a client of its own: httpx.Client is not shared between threads
        try:
            with httpx.Client(base_url=c.base_url, timeout=c.timeout) as up, log.open("rb") as fh:
                answer["r"] = up.post("/api/uploads", params={"name": f"{name}.csv"}, content=fh)
        except BaseException as e:  # handed to the measuring thread, raised there
            failed.append(e)

    t0 = time.monotonic()
    th = threading.Thread(target=send)
    th.start()
    busy = _lags_while(c, th, 0.0)
    th.join()
    took = time.monotonic() - t0
    if failed:
        raise failed[0]
    answer["r"].raise_for_status()
    return {
        "idle_p99": float(np.percentile(idle, 99)),
        "idle_max": max(idle),
        "upload_p99": float(np.percentile(busy, 99)),
        "upload_max": max(busy),
        "samples": float(len(busy)),
        "upload_s": took,
        "rss_growth_mb": (_peak_kb(pid) - rss0) / 1e3,
    }


def _start(data: Path) -> tuple[subprocess.Popen[bytes], str]:
    port = free_port()
    log = tempfile.TemporaryFile()
    cmd = [sys.executable, "-m", "server.cli.main", "serve", "--scenario", "default",
           "--no-viser", "--port", str(port), "--data-dir", str(data)]  # fmt: skip
    proc = subprocess.Popen(cmd, env=dict(os.environ), stdout=subprocess.DEVNULL, stderr=log)
    base = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 60
    while True:
        if proc.poll() is not None:
            log.seek(0)
            raise RuntimeError(f"cutwatch serve exited: {log.read().decode()[-500:]}")
        try:
            if httpx.get(f"{base}/api/health", timeout=1).json()["sim_t"] > 1.0:
                return proc, base
        except (httpx.HTTPError, KeyError):
            pass
        if time.monotonic() > deadline:
            proc.kill()
            raise RuntimeError("cutwatch serve did not come up in 60 s")
        time.sleep(0.2)


def measure(*, repeats: int, quick: bool) -> Figures:
    """``repeats`` idle windows and uploads of 80 MB (20 MB, 3 s windows with ``quick``)."""
    mb, idle_s = (20.0, 3.0) if quick else (MB, IDLE_S)
    with tempfile.TemporaryDirectory(prefix="cutwatch-bench-upload-") as d:
        log = Path(d) / "big.csv"
        rows = rigid_log(log, mb)
        size_mb = log.stat().st_size / 1e6
        proc, base = _start(Path(d) / "data")
        try:
            with httpx.Client(base_url=base, timeout=600) as c:
                runs = [_one(c, proc.pid, log, i, idle_s) for i in range(max(1, repeats))]
        finally:
            proc.terminate()
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()

    def med(k: str) -> float:
        return statistics.median(r[k] for r in runs)

    return {
        "upload_mb": size_mb,
        "upload_rows": rows,
        "runs": len(runs),
        "idle_window_s": idle_s,
        "loop_lag_p99_idle_ms": med("idle_p99"),
        "loop_lag_max_idle_ms": med("idle_max"),
        "loop_lag_p99_upload_ms": med("upload_p99"),
        "loop_lag_max_upload_ms": med("upload_max"),
        "loop_lag_p99_upload_over_idle": statistics.median(
            r["upload_p99"] / max(r["idle_p99"], 1e-3) for r in runs
        ),
        "lag_samples_per_upload": med("samples"),
        "upload_s": med("upload_s"),
        "upload_mb_per_s": size_mb / med("upload_s"),
        "rss_growth_mb_peak": med("rss_growth_mb"),
    }
