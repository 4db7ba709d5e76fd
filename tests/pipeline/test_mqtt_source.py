"""A log through a real broker into the live observers gives the file replay's estimates."""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np
import pytest
from _broker import broker

from common.errors import ParameterError
from server.cli.main import main
from server.pipeline.broker import parse_broker_url
from server.pipeline.drive_feed import DriveFeed
from server.pipeline.live_pipeline import LivePipeline
from server.pipeline.mqtt_source import MqttSource
from server.pipeline.sources import RESUMED, MeasurementSource
from server.records.measured_log import load_log, write_log


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("mqtt")
    assert main(["simulate", "--out", str(d / "run.csv"), "--seconds", "3"]) == 0
    log = load_log(d / "run.csv")
    cols = dict(log.columns)
    for k in ("tau_m", "f_ext"):  # what a float32 effort column carries
        cols[k] = cols[k].astype(np.float32).astype(np.float64)
    cols.pop("i_m", None)
    write_log(d / "run32.csv", cols, log.sidecar)
    return {"f64": d / "run.csv", "f32": d / "run32.csv"}


def fed(port: int, log: Path, *extra: str) -> DriveFeed:
    feed = DriveFeed(parse_broker_url(f"mqtt://127.0.0.1:{port}"), "m1", max_samples=10**7)
    feed.start()
    deadline = time.monotonic() + 10
    while not feed.connected and time.monotonic() < deadline:
        time.sleep(0.05)
    argv = ["feed", str(log), "--broker", f"mqtt://127.0.0.1:{port}", "--machine", "m1"]
    assert main([*argv, "--speed", "0", "--quiet", *extra]) == 0
    n = load_log(log).n
    while feed.buffered < n and time.monotonic() < deadline + 20:
        time.sleep(0.05)
    assert feed.buffered == n and feed.meta is not None
    return feed


def run(p: LivePipeline) -> dict[str, np.ndarray]:
    outs = []
    while True:
        o = p.step(125)
        if len(o["t"]) == 0:
            break
        outs.append(o)
    return {k: np.concatenate([o[k] for o in outs]) for k in outs[0]}


def compare(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> None:
    assert a.keys() == b.keys() and len(a["t"]) == len(b["t"]) > 0
    for k in a:
        if k.endswith("_true") or k.startswith("ecc"):
            continue
        scale = max(np.nanmax(np.abs(b[k])), 1e-300) if np.isfinite(b[k]).any() else 1.0
        np.testing.assert_allclose(a[k], b[k], rtol=1e-9, atol=1e-9 * scale, err_msg=k)


@pytest.mark.parametrize(("which", "extra"), [("f64", ["--float64"]), ("f32", [])])
def test_broker_feed_equals_the_file_replay(
    logs: dict[str, Path], which: str, extra: list[str]
) -> None:
    # float32 efforts on the wire: the same as replaying the log rounded to float32
    with broker() as port:
        feed = fed(port, logs["f64"], *extra)
        try:
            src = MqttSource(feed)
            assert isinstance(src, MeasurementSource) and src.ready, src.status()
            live = run(LivePipeline(source=src))
        finally:
            feed.stop()
    compare(live, run(LivePipeline.from_log(logs[which])))


def test_a_gap_resets_the_observers_like_a_fresh_start(logs: dict[str, Path]) -> None:
    with broker() as port:
        feed = fed(port, logs["f64"], "--float64")
        feed.stop()
    # drop blocks 8..11 from the buffer: a hole of 0.2 s in the middle
    kept = [x for i, x in enumerate(feed._blocks) if not 8 <= i < 12]
    feed._blocks.clear()
    feed._buffered = 0
    feed._next_seq = None
    for b, _, _ in kept:
        from server.records.drive_wire import encode_drive

        feed.push(encode_drive(b.seq, b.t0, b.sample_time, b.columns, {"effort": "N m",
                  "position": "rad"}, {k: "<f8" for k in b.columns}))  # fmt: skip
    assert feed.counts["gaps"] == 1 and feed.counts["missing_blocks"] == 4
    src = MqttSource(feed)
    p = LivePipeline(source=src)
    first = [p.step(125) for _ in range(8)]
    after = p.step(125)
    assert after["t"][0] == pytest.approx(12 * 125 * src.sample_time - src.sample_time)
    assert np.isfinite(np.concatenate([o["f_adaptive"] for o in first])).all()
    assert np.isfinite(after["f_adaptive"]).all()


def test_a_rigid_feed_is_taken_and_the_stage_says_why_it_does_not_run(tmp_path: Path) -> None:
    # issue 30: a rigid axis without a nominal is a machine like any other (it was refused:
    # "the live observers need a 'two_inertia' feed", 0 samples estimated)
    side = {"sample_time": 1e-3, "units": {"effort": "N", "position": "m"}, "kind": "rigid"}
    t = np.arange(500) * 1e-3
    write_log(tmp_path / "r.csv", {"t": t, "tau_m": np.sin(t), "q_m": t}, side)
    with broker() as port:
        feed = DriveFeed(parse_broker_url(f"mqtt://127.0.0.1:{port}"), "m1")
        feed.start()
        try:
            argv = ["feed", str(tmp_path / "r.csv"), "--broker", f"mqtt://127.0.0.1:{port}"]
            assert main([*argv, "--machine", "m1", "--speed", "0", "--quiet"]) == 0
            assert feed.wait_meta(5)
            src = MqttSource(feed)
            p = LivePipeline(source=src)
            out = p.step(125)
            st = src.status()
        finally:
            feed.stop()
    assert st["state"] == "receiving" and st["problem"] == ""
    assert out["t"].size == 125 and p.last_block is not None
    np.testing.assert_allclose(p.last_block.columns["tau_m"], np.sin(t[:125]), rtol=1e-6)
    assert np.isnan(p.last_block.meas.q_l).all()
    parts = {s["name"]: s for s in p.parts()}
    assert not parts["stage"]["running"] and "two_inertia" in str(parts["stage"]["reason"])
    json.dumps(st)  # health-ready


def test_a_restored_feed_goes_on_from_the_kept_time_and_says_it_resumed(
    logs: dict[str, Path],
) -> None:
    # the live sources' time (sources.LiveSource): kept in a checkpoint as a float,
    # continued after a restore with the next block marked resumed; reset starts at 0
    with broker() as port:
        feed = fed(port, logs["f64"], "--float64")
        feed.stop()
    src = MqttSource(feed)
    first = src.step(125)
    assert first.discontinuity is None and first.meas.t[0] == 0.0
    kept = src.state()
    assert kept == pytest.approx(125 * src.sample_time)
    again = MqttSource(feed)
    again.restore(kept)
    b = again.step(125)
    assert b.discontinuity == RESUMED
    assert b.meas.t[0] == pytest.approx(kept)
    assert again.step(125).discontinuity is None
    for bad in ("1.0", -1.0, math.nan):
        with pytest.raises(ParameterError) as err:
            again.restore(bad)
        assert err.value.name == "source"
    again.reset()
    assert again.state() == 0.0 and math.isnan(again.spindle_rpm)
