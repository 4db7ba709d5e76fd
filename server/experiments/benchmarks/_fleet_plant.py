"""The plant mode of ``cutwatch bench fleet``: N machines over W ``cutwatch worker``
processes, one feeder process for all machines, one ``cutwatch fleet`` page (see
:mod:`server.experiments.benchmarks.bench_fleet`'s docstring for what is measured)."""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import httpx
import numpy as np

from server.experiments.benchmarks import Figures
from server.experiments.benchmarks._local import free_port, mosquitto
from server.experiments.benchmarks.bench_fleet import (
    STALE_AFTER,
    _cpu,
    _cutwatch,
    _stop,
    _wait_http,
)

if TYPE_CHECKING:
    from server.experiments.benchmarks._plant_centres import PlantTruth

#: share of the window that is the steady state (then worker 0 is killed and restarted)
STEADY = 0.4


def _rss_mb(pid: int) -> float:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return 0.0


def _pct(a: list[float], q: float) -> float:
    return 1e3 * float(np.percentile(np.asarray(a), q)) if a else float("nan")


class _Plant:
    """The processes of one run (stopped by :meth:`stop`, whatever happened)."""

    def __init__(self, machines: int, workers: int, work: Path) -> None:
        self.names = [f"m{k:03d}" for k in range(machines)]
        self.n_workers = workers
        self.work = work
        self.bport, self.fport = free_port(), free_port()
        self.url = f"mqtt://127.0.0.1:{self.bport}"
        self.hports = [free_port() for _ in range(workers)]
        self.workers: list[subprocess.Popen[bytes]] = []
        self.others: list[subprocess.Popen[bytes]] = []
        self.feeder: subprocess.Popen[bytes] | None = None

    def worker(self, i: int) -> subprocess.Popen[bytes]:
        port = self.hports[i]
        return subprocess.Popen(
            _cutwatch("worker", "--broker", self.url, "--shard", f"{i}/{self.n_workers}",
                      "--data-dir", str(self.work / f"w{i}"), "--port", str(port),
                      "--public-url", f"http://127.0.0.1:{port}"),
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )  # fmt: skip

    def health(self, i: int) -> dict[str, Any]:
        try:
            h: dict[str, Any] = httpx.get(
                f"http://127.0.0.1:{self.hports[i]}/api/health", timeout=5
            ).json()
            return h
        except (httpx.HTTPError, ValueError):
            return {}

    def stop(self) -> None:
        procs = [p for p in (self.feeder,) if p is not None]
        _stop(procs + self.workers + self.others)


def _window(
    plant: _Plant, seconds: float, victim: set[str], soak: bool = False
) -> tuple[list[float], dict[str, float], dict[str, Any]]:
    """Watch the fleet page's stream: latencies and CPU over the steady window, then kill
    worker 0, restart it, and time its machines' return. ``soak``: the whole window is
    steady (no kill); the processes' memory is sampled every 30 s."""
    from websockets.sync.client import connect

    pids = {
        "broker": [plant.others[0].pid],
        "fleet": [plant.others[1].pid],
        "workers": [w.pid for w in plant.workers],
        "feeder": [plant.feeder.pid] if plant.feeder is not None else [],
    }
    lat: list[float] = []
    cpu0 = {k: sum(_cpu(p) for p in v) for k, v in pids.items()}
    t0 = time.monotonic()
    cpu: dict[str, float] = {}
    rec: dict[str, Any] = {}
    killed = restarted = None
    restarted_wall = 0.0
    back: dict[str, float] = {}
    rss: list[float] = []
    steady = 1.0 if soak else STEADY
    series: list[tuple[float, float, float, float]] = []  # (s, workers, fleet, broker) MB
    next_sample = 0.0
    with connect(f"ws://127.0.0.1:{plant.fport}/ws", max_size=2**24) as ws:
        while time.monotonic() - t0 < seconds:
            msg = json.loads(ws.recv(timeout=10))
            now = time.time()
            el = time.monotonic() - t0
            if "rows" in msg:
                continue
            if killed is None and msg.get("drive_wall") is not None:
                lat.append(now - float(msg["drive_wall"]))
            m = msg["machine"]
            if restarted is not None and m in victim and m not in back:
                # an estimate of a drive block published after the restart
                if (msg.get("drive_wall") or 0.0) > restarted_wall:
                    back[m] = time.monotonic() - restarted
            if soak and el >= next_sample:
                next_sample += 30.0
                mb = sum(_rss_mb(w.pid) for w in plant.workers)
                fleet_mb, broker_mb = _rss_mb(plant.others[1].pid), _rss_mb(plant.others[0].pid)
                series.append((round(el, 1), mb, fleet_mb, broker_mb))
            if soak and el > seconds - 0.5 and not cpu:
                cpu1 = {k: sum(_cpu(p) for p in v) for k, v in pids.items()}
                cpu = {k: 100.0 * (cpu1[k] - cpu0[k]) / el for k in pids}
                rss = [_rss_mb(w.pid) for w in plant.workers]
            if not soak and killed is None and el > seconds * steady:
                wall = el
                cpu1 = {k: sum(_cpu(p) for p in v) for k, v in pids.items()}
                cpu = {k: 100.0 * (cpu1[k] - cpu0[k]) / wall for k in pids}
                rss = [_rss_mb(w.pid) for w in plant.workers]
                plant.workers[0].send_signal(signal.SIGKILL)
                plant.workers[0].wait(10)
                killed = time.monotonic()
                plant.workers[0] = plant.worker(0)  # the supervisor restarts it at once
                restarted, restarted_wall = time.monotonic(), time.time()
    rec["rss_mb"] = rss
    if soak:
        rec["soak.memory_mb_series"] = series
        return lat, cpu, rec
    rec["restart.machines_back"] = len(back)
    rec["restart.seconds_to_all_back"] = max(back.values()) if len(back) == len(victim) else None
    rec["restart.seconds_to_first_back"] = min(back.values()) if back else None
    h0 = plant.health(0)
    rec["restart.resumed"] = h0.get("resumed")
    rec["restart.warm_s"] = h0.get("warm_s")
    return lat, cpu, rec


def _soak_figures(
    out: Figures, series: list[tuple[float, float, float, float]], lat: list[float]
) -> None:
    """Memory over the soak: first, last, max, and the slope of a line fitted to the
    second half (MB per 10 min; flat memory: near 0); latency p99 per tenth."""
    a = np.asarray(series)
    out["soak.samples"] = len(series)
    for j, name in ((1, "workers"), (2, "fleet"), (3, "broker")):
        out[f"soak.memory_mb.{name}.first"] = float(a[0, j])
        out[f"soak.memory_mb.{name}.last"] = float(a[-1, j])
        out[f"soak.memory_mb.{name}.max"] = float(a[:, j].max())
        h = a[len(a) // 2 :]
        slope = float(np.polyfit(h[:, 0], h[:, j], 1)[0]) if len(h) >= 3 else float("nan")
        out[f"soak.memory_mb.{name}.slope_per_10min_second_half"] = 600.0 * slope
    tenth = max(len(lat) // 10, 1)
    out["soak.latency_ms.p99_by_tenth"] = [
        round(_pct(lat[i : i + tenth], 99), 1) for i in range(0, len(lat), tenth)
    ][:10]
    out["soak.memory_mb_series"] = [[round(x, 1) for x in row] for row in series]


class _Events:
    """A subscriber to every machine's events (QoS 1) during the run: per machine, the
    monitor's events as ``{"kind", "t"}`` (t on the feed's clock)."""

    def __init__(self, port: int) -> None:
        import paho.mqtt.client as mqtt

        from common.event_kinds import ProcessEventKind

        kinds = {str(k) for k in ProcessEventKind}
        self.raised: dict[str, list[dict[str, Any]]] = {}

        def on_message(_c: object, _u: object, m: Any) -> None:
            try:
                d = json.loads(m.payload)
            except ValueError:
                return
            if d.get("kind") in kinds:
                name = m.topic.split("/")[1]
                self.raised.setdefault(name, []).append(
                    {"kind": d["kind"], "t": d["t"], "line": d.get("line")}
                )

        self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)
        self.client.on_message = on_message
        self.client.connect("127.0.0.1", port)
        self.client.subscribe("cutwatch/+/events", qos=1)
        self.client.loop_start()

    def stop(self) -> None:
        self.client.loop_stop()
        self.client.disconnect()


def _drive_log(
    log: Path, seconds: float, centres: bool, progress: bool, speed: float = 1.0
) -> PlantTruth | None:
    """The log the feeder replays: a machining centre's recorded trace (its events' truth
    returned) or the simulated stage (no truth)."""
    if centres:
        from server.experiments.benchmarks._plant_centres import record

        # longer than the window, the start and the rows' last check: the feed must not
        # end (the margin: 120 s at 1x, 25 s of wall faster)
        length = seconds * speed + (120.0 if speed <= 1.0 else 25.0 * speed)
        if progress:
            print(f"  plant: recording {length:g} s of a machining centre's trace",
                  file=sys.stderr, flush=True)  # fmt: skip
        return record(log, seconds=length)
    subprocess.run(
        _cutwatch("simulate", "--out", str(log), "--seconds", str(seconds + 120)),
        check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    return None


def _clocks(plant: _Plant) -> dict[str, tuple[float | None, float | None]]:
    """Per machine, from the worker that owns it: the pipeline's time and the machine's
    clock at its 0 (``feed_origin_s``); (None, None) where the worker does not answer."""
    from harness.shards import shard_of

    out: dict[str, tuple[float | None, float | None]] = {}
    for m in plant.names:
        port = plant.hports[shard_of(m, plant.n_workers)]
        try:
            d = httpx.get(f"http://127.0.0.1:{port}/api/machines/{m}", timeout=5).json()
            out[m] = (d.get("t"), d.get("feed_origin_s"))
        except (httpx.HTTPError, ValueError):
            out[m] = (None, None)
    return out


def _scored(
    events: _Events,
    truth: PlantTruth,
    names: list[str],
    clocks: dict[str, tuple[float | None, float | None]],
) -> Figures:
    """The monitors' events against the trace's truth, on each machine's own clock
    (``clocks``: the worker's time and origin per machine, :func:`_clocks`), up to the
    log's time every machine's pipeline has read; and one machine's beside the truth."""
    from server.experiments.benchmarks._plant_centres import on_machine_clock, score

    origins = {m: o for m, (_, o) in clocks.items()}
    read = [t + (o or 0.0) for t, o in clocks.values() if t is not None]
    t_read = min(read) if len(read) == len(names) else 0.0  # a machine not read: none due
    raised = on_machine_clock({m: events.raised.get(m, []) for m in names}, origins)
    sc = score(truth["events"], raised, min(t_read, float(truth["seconds"])))
    out: Figures = {
        "monitor.events_due": sc["events_due"],
        "monitor.found": sc["found"],
        "monitor.beside": sc["beside"],
        "monitor.false": sc["false"],
        "monitor.detection": sc["detection"],
    }
    out["monitor.events_in_trace"] = len(truth["events"])
    out["monitor.teach_parts"] = truth["teach_parts"]
    # the log's time the slowest machine's pipeline had read (not the wall time since
    # the feeder started: it reads the whole log first, 10-20 s on a loaded box)
    out["monitor.feed_s"] = t_read
    out["monitor.join_s"] = [round(o, 3) if o is not None else None for o in origins.values()]
    out["monitor.truth"] = [[e["kind"], round(e["t"], 2), e["line"]] for e in truth["events"]]
    out["monitor.raised_m000"] = [
        [e["kind"], round(float(e["t"]), 2), e["line"]] for e in raised.get(names[0], [])
    ]
    out["monitor.raised_per_machine"] = [len(raised[m]) for m in names]
    return out


def run_plant(
    machines: int,
    workers: int,
    seconds: float,
    progress: bool,
    soak: bool = False,
    centres: bool = False,
    feed_speed: float = 1.0,
) -> Figures:
    """One plant run (module docstring); ``soak``: no kill, memory sampled over time.
    ``centres``: the machines are machining centres at 500 Hz, every one replaying one
    recorded trace (:mod:`._plant_centres`), run as a soak (no kill: the monitors' events
    are scored against the trace's truth). ``feed_speed``: log seconds per wall second
    (``cutwatch feed --speed``; a test's quick plant reaches the trace's events sooner;
    the costs are then those of that many more samples per second)."""
    from harness.shards import shard_of

    work = Path(tempfile.mkdtemp(prefix="cutwatch-bench-plant-"))
    log = work / "drive.csv"
    truth = _drive_log(log, seconds, centres, progress, feed_speed)
    soak = soak or centres
    plant = _Plant(machines, workers, work)
    what = "machining centres at 500 Hz, one recorded trace replayed" if centres else "machines"
    out: Figures = {
        "configuration": (
            f"1 cutwatch feed ({machines} {what}) -> mosquitto -> {workers} x cutwatch "
            "worker (100 ms blocks, estimates at 10 Hz) -> cutwatch fleet; 2-core machine"
        ),
        "machines": machines,
        "workers": workers,
    }
    events: _Events | None = None
    try:
        with mosquitto(plant.bport) as broker:
            plant.others.append(broker)
            plant.others.append(subprocess.Popen(
                _cutwatch("fleet", "--broker", plant.url, "--port", str(plant.fport),
                          "--stale-after", str(STALE_AFTER)),
                stdout=subprocess.DEVNULL,
            ))  # fmt: skip
            plant.workers = [plant.worker(i) for i in range(workers)]
            for i in range(workers):
                _wait_http(f"http://127.0.0.1:{plant.hports[i]}/api/health", 120)
            deadline = time.monotonic() + 180
            while not all(plant.health(i).get("status") == "ok" for i in range(workers)):
                if time.monotonic() > deadline:
                    raise RuntimeError("the workers did not get ready within 180 s")
                time.sleep(0.5)
            idle = [_rss_mb(w.pid) for w in plant.workers]
            _wait_http(f"http://127.0.0.1:{plant.fport}/api/health", 60)
            if centres:
                events = _Events(plant.bport)
            plant.feeder = subprocess.Popen(
                _cutwatch("feed", str(log), "--broker", plant.url, "--speed", f"{feed_speed:g}",
                          "--machine", ",".join(plant.names), "--quiet"),
                stdout=subprocess.DEVNULL,
            )  # fmt: skip
            deadline = time.monotonic() + 180
            while True:
                rows = httpx.get(f"http://127.0.0.1:{plant.fport}/api/fleet", timeout=5).json()
                if sum(r["status"] == "ok" for r in rows) == machines:
                    break
                if time.monotonic() > deadline:
                    break  # measured as it is: the rows ok say how many made it
                time.sleep(1.0)
            if progress:
                print(f"  plant: {len(rows)} rows, measuring {seconds:g} s", file=sys.stderr,
                      flush=True)  # fmt: skip
            time.sleep(2 * STALE_AFTER)
            rows = httpx.get(f"http://127.0.0.1:{plant.fport}/api/fleet", timeout=5).json()
            out["fleet.rows"] = len(rows)
            out["fleet.ok_at_start"] = sum(r["status"] == "ok" for r in rows)
            victim = {m for m in plant.names if shard_of(m, workers) == 0}
            lat, cpu, rec = _window(plant, seconds, victim, soak)
            for k, v in cpu.items():
                out[f"cpu_pct_one_core.{k}"] = v
            out["cpu_pct_one_core.workers_per_machine"] = cpu["workers"] / machines
            rss = rec.pop("rss_mb")
            out["memory_mb.workers"] = sum(rss)
            out["memory_mb.workers_idle"] = sum(idle)
            out["memory_mb.per_machine"] = sum(rss) / machines
            out["memory_mb.per_machine_marginal"] = (sum(rss) - sum(idle)) / machines
            out["latency_ms.p50"] = _pct(lat, 50)
            out["latency_ms.p99"] = _pct(lat, 99)
            out["latency_ms.max"] = 1e3 * max(lat) if lat else float("nan")
            out["latency.samples"] = len(lat)
            if not soak:
                out["restart.machines"] = len(victim)
            else:
                _soak_figures(out, rec.pop("soak.memory_mb_series"), lat)
            out.update(rec)
            time.sleep(2 * STALE_AFTER)
            rows = httpx.get(f"http://127.0.0.1:{plant.fport}/api/fleet", timeout=5).json()
            out["fleet.ok_at_end"] = sum(r["status"] == "ok" for r in rows)
            # a machine whose monitor raised an event is live, its row says "alarm"
            out["fleet.alarm_at_end"] = sum(r["status"] == "alarm" for r in rows)
            hs = [plant.health(i) for i in range(workers)]
            out["workers.dropped_samples"] = sum(int(h.get("dropped_samples", 0)) for h in hs)
            out["workers.loop_ms_p50"] = max(float(h.get("loop_ms_p50") or 0) for h in hs)
            if events is not None and truth is not None:  # both with centres
                out.update(_scored(events, truth, plant.names, _clocks(plant)))
    finally:
        if events is not None:
            events.stop()
        plant.stop()
        shutil.rmtree(work, ignore_errors=True)
    return out
