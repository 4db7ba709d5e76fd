"""The broker feed's checks: gaps, duplicates, late blocks, restarts, floods, bad payloads."""

from __future__ import annotations

import time

import numpy as np
import pytest
from _broker import broker, free_port

from server.pipeline.broker import parse_broker_url
from server.pipeline.drive_feed import DriveFeed
from server.records.drive_wire import encode_drive, encode_meta

TS = 4e-4
N = 125
UNITS = {"effort": "N m", "position": "rad"}
META = {"sample_time": TS, "units": UNITS, "kind": "two_inertia", "nominal": {}}


def blk(seq: int, t0: float | None = None, units: dict[str, str] = UNITS, ts: float = TS) -> bytes:
    t0 = seq * N * ts if t0 is None else t0
    k = np.arange(N) + round(t0 / ts)
    cols = {"tau_m": np.sin(k * 1e-2), "q_m": k * 1e-3, "q_l": k * 1e-3}
    return encode_drive(seq, t0, ts, cols, units)


def feed() -> DriveFeed:
    f = DriveFeed(parse_broker_url("mqtt://127.0.0.1:1"), "m1", max_samples=10 * N)
    f._meta(encode_meta(META))
    return f


def test_in_order_blocks_come_out_contiguous() -> None:
    f = feed()
    for s in range(4):
        f.push(blk(s))
    a = f.take(300)
    b = f.take(1000)
    assert (a.n, b.n) == (300, 200) and not a.discontinuity and not b.discontinuity
    t = np.concatenate([a.t, b.t])
    np.testing.assert_allclose(np.diff(t), TS, rtol=1e-9)
    assert f.counts["blocks"] == 4 and f.counts["gaps"] == 0 and f.take(10).n == 0


def test_a_missing_block_is_a_gap_and_starts_a_new_segment() -> None:
    f = feed()
    f.push(blk(0))
    f.push(blk(2))
    first = f.take(1000)
    second = f.take(1000)
    assert first.n == N and not first.discontinuity
    assert second.n == N and second.discontinuity and "1 block(s) missing" in second.reasons
    assert f.counts["gaps"] == 1 and f.counts["missing_blocks"] == 1


def test_a_time_jump_with_continuous_seq_is_a_gap() -> None:
    f = feed()
    f.push(blk(0))
    f.push(blk(1, t0=5.0))
    f.take(N)
    assert f.take(N).discontinuity and f.counts["gaps"] == 1


def test_duplicates_and_late_blocks_are_dropped_and_counted() -> None:
    f = feed()
    for s in (0, 1, 1, 3, 2):  # 1 twice; 2 arrives after 3
        f.push(blk(s))
    assert f.counts["duplicates"] == 1 and f.counts["out_of_order"] == 1
    assert f.counts["gaps"] == 1  # 3 came when 2 was expected
    assert f.take(10_000).n + f.take(10_000).n == 3 * N


def test_a_publisher_restart_is_a_new_segment() -> None:
    f = feed()
    for s in range(3):
        f.push(blk(s))
    f.push(blk(0))
    f.take(10_000)
    assert f.take(10_000).discontinuity and f.counts["restarts"] == 1


def test_a_flood_keeps_the_newest_samples_and_counts_the_rest() -> None:
    f = feed()
    for s in range(30):
        f.push(blk(s))
    assert f.buffered <= 10 * N
    assert f.counts["dropped_samples"] == 20 * N
    first = f.take(N)
    assert first.discontinuity and any("overflow" in r for r in first.reasons)
    assert first.t[0] == pytest.approx(20 * N * TS)


@pytest.mark.parametrize(
    ("payload", "counter"),
    [
        (b"garbage", "malformed_schema"),
        (blk(0).replace(b'"version":1', b'"version":9'), "malformed_version"),
        (blk(0, units={"effort": "N", "position": "rad"}), "malformed_units"),
        (blk(0, ts=1e-3), "malformed_units"),
        (blk(0)[:-8], "malformed_shape"),
    ],
)
def test_malformed_payloads_are_counted_and_skipped(payload: bytes, counter: str) -> None:
    f = feed()
    f.push(payload)
    assert f.counts[counter] == 1 and f.buffered == 0
    f.push(blk(0))
    assert f.buffered == N  # the feed goes on


def test_a_broker_down_at_start_is_reported_and_joined_when_it_comes_up() -> None:
    port = free_port()
    f = DriveFeed(parse_broker_url(f"mqtt://127.0.0.1:{port}"), "m1")
    f.start()
    try:
        time.sleep(0.5)
        assert not f.health()["connected"]
        with broker(port=port):
            deadline = time.monotonic() + 40  # paho's backoff is 1..30 s
            while not f.health()["connected"] and time.monotonic() < deadline:
                time.sleep(0.2)
            assert f.health()["connected"]
    finally:
        f.stop()


def test_a_wrong_password_is_a_clear_error_in_health() -> None:
    with broker(users={"edge": "right"}) as port:
        cfg = parse_broker_url(f"mqtt://edge:wrong@127.0.0.1:{port}")
        f = DriveFeed(cfg, "m1")
        f.start()
        try:
            deadline = time.monotonic() + 10
            while not f.health()["error"] and time.monotonic() < deadline:
                time.sleep(0.1)
            h = f.health()
        finally:
            f.stop()
    assert not h["connected"] and "refused" in h["error"] and "wrong" not in h["error"]
