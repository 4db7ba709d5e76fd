"""Recording the live source through the real app: start, stop, list, download, and the
recording read back by ``cutwatch residual`` (the round trip); the 409s; a gap, a
pipeline change and shutdown end a recording with nothing lost."""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from _live import serve
from _wait import poll

from machine.stage import Measurements
from server.cli.main import main
from server.pipeline.live_pipeline import LivePipeline
from server.pipeline.sources import SourceBlock
from server.records.measured_log import load_log
from server.service.recording import Recording

COLUMNS = ["t", "tau_m", "i_m", "q_m", "q_l", "f_ext"]


def wait_for(pred: Callable[[], Any], timeout: float = 30.0) -> Any:
    return poll(pred, timeout, 0.05)


@pytest.fixture(scope="module")
def data(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("data")


@pytest.fixture(scope="module")
def api(data: Path) -> Iterator[httpx.Client]:
    with (
        serve(scenario="default", data_dir=data) as hp,
        httpx.Client(base_url=f"http://{hp}", timeout=30) as c,
    ):
        yield c


def one_error(r: httpx.Response, status: int) -> dict[str, Any]:
    assert r.status_code == status, r.text
    (err,) = r.json()["detail"]
    assert set(err) == {"field", "allowed", "got", "msg"}
    return dict(err)


def test_record_refusals(api: httpx.Client) -> None:
    err = one_error(api.post("/api/record", json={"action": "stop"}), 409)
    assert err["msg"] == "not recording" and err["field"] == "action"
    assert api.post("/api/control", json={"action": "pause"}).is_success
    err = one_error(api.post("/api/record", json={"action": "start"}), 409)
    assert err["msg"] == "nothing runs: the loop is paused (resume it: POST /api/control)"
    assert api.get("/api/records").json() == {"records": []}
    assert api.post("/api/control", json={"action": "resume"}).is_success
    for bad in ("../x", "/etc/passwd", ".hidden", "a b", "x.txt", ""):
        err = one_error(api.post("/api/record", json={"action": "start", "name": bad}), 422)
        assert err["field"] == "name" and err["got"] == bad
    err = one_error(api.post("/api/record", json={"action": "begin"}), 422)
    assert err["field"] == "action"


def test_record_round_trip_into_cutwatch_residual(api: httpx.Client, tmp_path: Path) -> None:
    # a simulated run with an unmodelled effect, from t = 0 (reset keeps the knob)
    assert api.post("/api/control", json={"action": "scenario", "scenario": "seed000-weight"})
    assert api.patch("/api/params", json={"effect_coulomb_asymmetry": True}).is_success
    assert api.post("/api/control", json={"action": "speed", "value": 5}).is_success
    assert api.post("/api/control", json={"action": "reset"}).is_success
    r = api.post("/api/record", json={"action": "start", "name": "run1"})
    assert r.status_code == 200, r.text
    assert r.json()["recording"]["name"] == "run1.csv" and r.json()["recording"]["active"]
    err = one_error(api.post("/api/record", json={"action": "start"}), 409)
    assert err["msg"] == "already recording 'run1.csv': stop it first"
    listed = wait_for(lambda: (v := api.get("/api/records").json()["records"])[0]["seconds"] and v)
    assert listed[0]["name"] == "run1.csv" and listed[0]["active"]
    wait_for(lambda: api.get("/api/records").json()["records"][0]["seconds"] > 7.0)
    stop = api.post("/api/record", json={"action": "stop"})
    assert stop.status_code == 200, stop.text
    rec = stop.json()["recording"]
    assert not rec["active"] and rec["end"] == "stopped" and rec["seconds"] > 7.0
    (listed1,) = api.get("/api/records").json()["records"]
    assert listed1 == {**rec, "bytes": listed1["bytes"]} and listed1["bytes"] > 0
    err = one_error(api.post("/api/record", json={"action": "start", "name": "run1"}), 409)
    assert err["msg"] == "recording 'run1.csv' exists already"

    # download: the CSV and its sidecar
    got = api.get("/api/records/run1.csv")
    assert got.status_code == 200 and got.headers["content-type"].startswith("text/csv")
    assert api.get("/api/records/run1").content == got.content
    side = api.get("/api/records/run1/sidecar").json()
    assert side["kind"] == "two_inertia" and side["sample_time"] == 4e-4
    assert side["units"] == {"effort": "N m", "position": "rad", "current": "A"}
    assert side["recording"]["samples"] == rec["samples"]
    rows = list(csv.reader(io.StringIO(got.text)))
    assert rows[0] == COLUMNS
    arr = np.array(rows[1:], dtype=np.float64)
    assert len(arr) == rec["samples"]
    k = np.rint(arr[:, 0] / 4e-4).astype(np.int64)
    assert np.array_equal(np.diff(k), np.ones(len(k) - 1, dtype=np.int64))  # none lost

    # the samples are what the source delivered: the same simulation offline
    p = LivePipeline("seed000-weight")
    p.set_knob("effect_coulomb_asymmetry", True)
    blocks = []
    while p.t < (k[-1] + 1) * 4e-4 - 1e-9:
        p.step(125)
        assert p.last_block is not None
        blocks.append(p.last_block.meas)
    ref = np.column_stack([np.concatenate([getattr(m, c) for m in blocks]) for c in COLUMNS])
    assert np.array_equal(arr, ref[k])  # bit for bit (round-trip text)

    # the round trip: cutwatch residual reads the recording
    (tmp_path / "run1.csv").write_bytes(got.content)
    (tmp_path / "run1.json").write_text(json.dumps(side))
    assert load_log(tmp_path / "run1.csv").n == rec["samples"]
    out = tmp_path / "rep"
    assert main(["residual", str(tmp_path / "run1.csv"), "--out", str(out), "--quiet"]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert rep["kind"] == "two_inertia" and rep["n_samples"] == rec["samples"]
    assert rep["rms_after"] < rep["rms_before"]
    assert api.patch("/api/params", json={"effect_coulomb_asymmetry": False}).is_success
    assert api.post("/api/control", json={"action": "speed", "value": 1}).is_success


def test_a_pipeline_change_ends_the_recording(api: httpx.Client, data: Path) -> None:
    assert api.post("/api/record", json={"action": "start", "name": "cut2"}).status_code == 200
    wait_for(lambda: api.get("/api/records").json()["records"][0]["samples"])
    assert api.post("/api/control", json={"action": "scenario", "scenario": "default"})
    rec = wait_for(
        lambda: next(
            (r for r in api.get("/api/records").json()["records"] if r["name"] == "cut2.csv"),
            None,
        )
    )
    assert not rec["active"] and rec["end"] == "the pipeline changed"
    log = load_log(data / "recordings" / "cut2.csv")
    assert log.n == rec["samples"] > 0
    err = one_error(api.post("/api/record", json={"action": "stop"}), 409)
    assert err["msg"] == "not recording"


@pytest.mark.parametrize(
    "name", ["../recordings/run1.csv", "..", "%2e%2e%2frun1.csv", "nope.csv", ".run1.csv.tmp"]
)
def test_download_by_plain_name_only(api: httpx.Client, name: str) -> None:
    err = one_error(api.get(f"/api/records/{name}"), 404)
    assert "no item named" in err["msg"] or "no route" in err["msg"]


def test_shutdown_closes_the_recording(tmp_path: Path) -> None:
    with (
        serve(scenario="default", data_dir=tmp_path, speed=5) as hp,
        httpx.Client(base_url=f"http://{hp}") as c,
    ):
        assert c.post("/api/record", json={"action": "start", "name": "last"}).is_success
        wait_for(lambda: c.get("/api/records").json()["records"][0]["seconds"] > 1.0)
    side = json.loads((tmp_path / "recordings" / "last.json").read_text())
    assert side["recording"]["end"] == "the service stopped"
    log = load_log(tmp_path / "recordings" / "last.csv")
    assert log.n == side["recording"]["samples"] > 2500
    assert not list((tmp_path / "recordings").glob(".*"))  # no temporary file left


def _block(k0: int, n: int, gap: str | None = None) -> SourceBlock:
    t = (k0 + np.arange(n)) * 1e-3
    z = np.sin(t)
    return SourceBlock(Measurements(t=t, i_m=z, tau_m=z, q_m=z, q_l=z, f_ext=z), None, gap)


def test_a_gap_ends_the_recording_before_it(tmp_path: Path) -> None:
    side = {"sample_time": 1e-3, "units": {"effort": "N m", "position": "rad"}, "kind": "rigid"}
    rec = Recording(tmp_path / "g.csv", side, max_bytes=1e9, max_seconds=1e9)
    for i in range(4):
        rec.feed(_block(10 * i, 10))
    rec.feed(_block(100, 10, gap="gap"))
    rec.feed(_block(110, 10))  # after the gap: not in this recording
    assert not rec.active
    done = rec.wait()
    assert done["samples"] == 40 and done["end"] == "source discontinuity (gap)"
    log = load_log(tmp_path / "g.csv")
    assert log.n == 40 and log.sample_time == pytest.approx(1e-3)


def test_the_duration_limit_ends_the_recording(tmp_path: Path) -> None:
    side = {"sample_time": 1e-3, "units": {"effort": "N m", "position": "rad"}}
    rec = Recording(tmp_path / "d.csv", side, max_bytes=1e9, max_seconds=0.025)
    for i in range(6):
        rec.feed(_block(10 * i, 10))
    done = rec.wait()
    assert done["samples"] == 30 and done["end"] == "duration limit 0.025 s reached"
    assert load_log(tmp_path / "d.csv").n == 30


def test_a_gap_in_a_broker_feed_ends_the_recording_in_the_loop(tmp_path: Path) -> None:
    """A real Mosquitto carries a log with a hole into the running loop; the recording
    ends at the hole with every sample before it, and the log stays valid."""
    from _broker import broker

    from server.pipeline.broker import parse_broker_url
    from server.pipeline.drive_feed import DriveFeed
    from server.pipeline.mqtt_source import MqttSource
    from server.records.drive_wire import encode_drive
    from server.service.hub import Hub
    from server.service.loop import LiveLoop
    from server.service.recording import source_sidecar
    from server.service.settings import Settings

    log = tmp_path / "run.csv"
    assert main(["simulate", "--out", str(log), "--seconds", "3"]) == 0
    n = load_log(log).n
    with broker() as port:
        url = f"mqtt://127.0.0.1:{port}"
        feed = DriveFeed(parse_broker_url(url), "m1", max_samples=10**7)
        feed.start()
        wait_for(lambda: feed.connected, 10)
        argv = ["feed", str(log), "--broker", url, "--machine", "m1", "--speed", "0"]
        assert main([*argv, "--quiet", "--float64"]) == 0
        wait_for(lambda: feed.buffered == n, 20)
        feed.stop()
    blocks = list(feed._blocks)  # a hole: blocks 8..11 never arrived
    feed._blocks.clear()
    feed._buffered = 0
    feed._next_seq = None
    for b, _, _ in [x for i, x in enumerate(blocks) if not 8 <= i < 12]:
        feed.push(encode_drive(b.seq, b.t0, b.sample_time, b.columns, {"effort": "N m",
                  "position": "rad"}, {k: "<f8" for k in b.columns}))  # fmt: skip
    before_gap = sum(len(b.columns["q_m"]) for b, _, _ in blocks[:8])

    lp = LiveLoop(Settings(scenario="default", viser=False, speed=10, data_dir=tmp_path), Hub(4))
    lp.start()
    try:
        with lp.lock:  # the recording from the pipeline's first block on
            lp.set_pipeline(LivePipeline(source=MqttSource(feed)))
            side = source_sidecar(lp.pipeline.source, lp.pipeline.scenario)
            lp.recording = rec = Recording(
                tmp_path / "feed.csv", side, max_bytes=1e9, max_seconds=1e9
            )
        done = rec.wait(30)
    finally:
        lp.stop()
    assert done["end"] == "source discontinuity (4 block(s) missing)" and not done["active"]
    assert done["samples"] == before_gap
    got = load_log(tmp_path / "feed.csv")
    ref = load_log(log)
    assert got.n == before_gap and "f_ext" in got.columns
    for c in ("tau_m", "q_m", "q_l", "f_ext"):
        np.testing.assert_array_equal(got[c], ref[c][:before_gap], err_msg=c)
