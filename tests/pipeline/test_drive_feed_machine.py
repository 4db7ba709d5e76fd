"""A machine's drive blocks through the feed: every column kept, unknown ones counted, the
identities handed out per sample, a block never lost for a column it has too many."""

from __future__ import annotations

import numpy as np

from server.pipeline.broker import parse_broker_url
from server.pipeline.drive_feed import DriveFeed
from server.records.drive_wire import Segment, encode_drive, encode_meta

TS = 2e-3
N = 25
MACHINE = {
    "sample_time": TS,
    "axes": {
        "X": {"kind": "rigid", "signals": {"q_m": "X_q", "i_m": "X_i"}, "units": {"position": "m"}},
        "Z": {
            "kind": "rigid",
            "signals": {"q_m": "Z_q", "i_m": "Z_i", "qdd_cmd": "Z_acmd"},
            "units": {"position": "m"},
        },
    },
    "spindle": {"signals": {"speed": "S_n", "power": "S_p"}, "units": {"power": "kW"}},
    "identities": {"tool": "T", "line": "N"},
}
UNITS = {"X_q": "m", "X_i": "A", "Z_q": "m", "Z_i": "A", "Z_acmd": "m/s^2"}
UNITS |= {"S_n": "rpm", "S_p": "kW", "temp": ""}


def blk(seq: int, extra: bool = False, acc: bool = True, segs: bool = True) -> bytes:
    k = np.arange(N) + seq * N
    cols = {
        "X_q": k * 1e-5,
        "X_i": np.sin(k * 0.1),
        "Z_q": -k * 1e-6,
        "Z_i": np.cos(k * 0.1),
        "S_n": np.full(N, 6000.0),
        "S_p": np.full(N, 2.5),
    }
    if acc:
        cols["Z_acmd"] = np.zeros(N)
    if extra:
        cols["temp"] = np.full(N, 40.0)
    seg = [Segment(0, 2, 10 + seq), Segment(10, 2, 11 + seq, 1.1)] if segs else []
    return encode_drive(seq, seq * N * TS, TS, cols, UNITS, program="O100", segments=seg)


def feed() -> DriveFeed:
    f = DriveFeed(parse_broker_url("mqtt://127.0.0.1:1"), "mc1", max_samples=100 * N)
    f.push_meta(encode_meta(MACHINE))
    return f


def test_every_column_of_the_machine_comes_out_and_extra_ones_are_counted() -> None:
    f = feed()
    assert f.description is not None and f.description.axis_names == ("X", "Z")
    for s in range(4):
        f.push(blk(s, extra=s % 2 == 1))
    take = f.take(10_000)
    assert take.n == 4 * N and f.counts["blocks"] == 4  # no block lost
    assert f.counts["ignored_columns"] == 2 and f.health()["ignored_names"] == ["temp"]
    assert set(take.columns) == {"X_q", "X_i", "Z_q", "Z_i", "Z_acmd", "S_n", "S_p"}
    np.testing.assert_allclose(take.columns["X_q"], np.arange(4 * N) * 1e-5)
    np.testing.assert_array_equal(take.columns["S_p"], 2.5)


def test_an_optional_column_missing_from_a_block_is_nan_not_a_lost_block() -> None:
    f = feed()
    f.push(blk(0))
    f.push(blk(1, acc=False))
    take = f.take(10_000)
    assert take.n == 2 * N
    assert (
        np.isnan(take.columns["Z_acmd"][N:]).all()
        and not np.isnan(take.columns["Z_acmd"][:N]).any()
    )


def test_a_required_column_missing_is_counted_and_the_feed_goes_on() -> None:
    f = feed()
    bad = encode_drive(0, 0.0, TS, {"X_q": np.zeros(N), "Z_q": np.zeros(N)}, UNITS)
    f.push(bad)
    assert f.counts["malformed_shape"] == 1 and f.buffered == 0
    f.push(blk(0))
    assert f.buffered == N


def test_identities_come_out_per_sample_across_blocks_and_partial_takes() -> None:
    f = feed()
    f.push(blk(0))
    f.push(blk(1, segs=False))
    f.push(blk(2))
    a = f.take(15)  # a partial block: the rest keeps its identities
    b = f.take(10_000)
    assert a.program == "O100" and b.program == "O100"
    line = np.concatenate([a.identities["line"], b.identities["line"]])
    want = [10] * 10 + [11] * 15 + [np.nan] * N + [12] * 10 + [13] * 15
    np.testing.assert_array_equal(line, want)
    override = np.concatenate([a.identities["override"], b.identities["override"]])
    assert np.isnan(override[:10]).all() and (override[10:25] == 1.1).all()


def test_a_new_description_is_a_new_generation_and_a_break() -> None:
    f = feed()
    gen = f.meta_generation
    f.push_meta(encode_meta(MACHINE))  # the same machine again (retained on reconnect)
    assert f.meta_generation == gen
    f.push(blk(0))
    f.take(10_000)
    f.push_meta(encode_meta({**MACHINE, "sample_time": 1e-3}))
    assert f.meta_generation == gen + 1
    f.push(encode_drive(1, N * TS, 1e-3, {"X_q": np.zeros(N), "X_i": np.zeros(N),
                                            "Z_q": np.zeros(N), "Z_i": np.zeros(N),
                                            "S_n": np.zeros(N)}, UNITS))  # fmt: skip
    t = f.take(10_000)
    assert t.discontinuity and "meta changed" in t.reasons


def test_an_old_single_axis_publisher_is_still_read() -> None:
    old_meta = {"sample_time": 4e-4, "units": {"effort": "N m", "position": "rad"},
                "kind": "two_inertia", "nominal": {}}  # fmt: skip
    f = DriveFeed(parse_broker_url("mqtt://127.0.0.1:1"), "m1")
    f.push_meta(encode_meta(old_meta))
    cols = {"tau_m": np.ones(N), "q_m": np.zeros(N), "q_l": np.zeros(N)}
    f.push(encode_drive(0, 0.0, 4e-4, cols, {"effort": "N m", "position": "rad"}))
    take = f.take(1000)
    assert take.n == N and set(take.columns) == {"tau_m", "q_m", "q_l", "f_ext"}
    assert np.isnan(take.columns["f_ext"]).all() and take.identities == {}
