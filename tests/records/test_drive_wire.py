"""The broker's wire format: round trips, and every malformed payload named by kind."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from server.records.drive_wire import (
    WireError,
    decode_drive,
    decode_meta,
    encode_drive,
    encode_drive_json,
    encode_meta,
)

UNITS = {"effort": "N m", "position": "rad"}


def block(n: int = 125, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {
        "tau_m": rng.normal(size=n),
        "q_m": np.cumsum(rng.normal(size=n)) * 1e3,
        "q_l": np.cumsum(rng.normal(size=n)),
        "f_ext": rng.normal(size=n),
    }


@settings(max_examples=40, deadline=None)
@given(n=st.integers(0, 400), seed=st.integers(0, 10_000), f64=st.booleans())
def test_round_trip(n: int, seed: int, f64: bool) -> None:
    cols = block(n, seed)
    dtypes = {k: "<f8" for k in cols} if f64 else None
    b = decode_drive(encode_drive(7, 1.25, 4e-4, cols, UNITS, dtypes))
    assert (b.seq, b.t0, b.sample_time, b.n) == (7, 1.25, 4e-4, n)
    for k, v in cols.items():
        if f64 or k in ("q_m", "q_l"):  # positions always travel as float64
            np.testing.assert_array_equal(b.columns[k], v)
        else:
            np.testing.assert_array_equal(b.columns[k], v.astype(np.float32))
    np.testing.assert_allclose(b.t, 1.25 + np.arange(n) * 4e-4)


def test_binary_is_smaller_than_json() -> None:
    cols = block()
    assert (
        len(encode_drive(0, 0.0, 4e-4, cols, UNITS))
        < len(encode_drive_json(0, 0.0, 4e-4, cols, UNITS)) / 2.5
    )


def _with_header(payload: bytes, **changes: object) -> bytes:
    head, body = payload.split(b"\n", 1)
    h = json.loads(head)
    h.update(changes)
    return json.dumps(h).encode() + b"\n" + body


GOOD = encode_drive(0, 0.0, 4e-4, block(10), UNITS)


@pytest.mark.parametrize(
    ("payload", "kind", "match"),
    [
        (b"no header at all", "schema", "no JSON header"),
        (b"{not json\n", "schema", "not JSON"),
        (_with_header(GOOD, schema="other"), "schema", "schema expected"),
        (_with_header(GOOD, version=2), "version", "version expected 1, got 2"),
        (_with_header(GOOD, n=11), "shape", "columns need more"),
        (_with_header(GOOD, n=9), "shape", "columns take"),
        (_with_header(GOOD, sample_time=0), "value", "sample_time"),
        (_with_header(GOOD, seq="3"), "schema", "field 'seq'"),
        (
            _with_header(
                GOOD,
                columns=[
                    {"name": "tau_m", "dtype": "<f4", "unit": "N m"},
                    {"name": "q_m", "dtype": "<f8", "unit": "deg"},
                    {"name": "q_l", "dtype": "<f8", "unit": "rad"},
                    {"name": "f_ext", "dtype": "<f4", "unit": "N m"},
                ],
            ),
            "units",
            "unit expected one of \\['m', 'rad'\\], got 'deg'",
        ),
        (GOOD + b"xx", "shape", "columns take"),
    ],
)
def test_malformed_blocks_are_named(payload: bytes, kind: str, match: str) -> None:
    with pytest.raises(WireError, match=match) as err:
        decode_drive(payload)
    assert err.value.kind == kind


def test_a_block_needs_position_and_effort() -> None:
    cols = block(5)
    del cols["tau_m"]
    with pytest.raises(WireError, match="expected q_m and tau_m or i_m"):
        decode_drive(encode_drive(0, 0.0, 1e-3, cols, UNITS))


def test_non_finite_samples_are_refused_but_f_ext_may_be_missing() -> None:
    cols = block(5)
    cols["f_ext"][:] = np.nan
    assert np.isnan(decode_drive(encode_drive(0, 0.0, 1e-3, cols, UNITS)).columns["f_ext"]).all()
    cols["q_m"][2] = np.inf
    with pytest.raises(WireError, match="'q_m': non-finite") as err:
        decode_drive(encode_drive(0, 0.0, 1e-3, cols, UNITS))
    assert err.value.kind == "value"


def test_meta_round_trip_and_checks() -> None:
    side = {
        "sample_time": 4e-4,
        "units": UNITS,
        "kind": "two_inertia",
        "nominal": {"J_L": 1e-3},
        "other": 1,
    }
    d = decode_meta(encode_meta(side))
    assert d["nominal"] == {"J_L": 1e-3} and "other" not in d and d["version"] == 1
    with pytest.raises(WireError, match=r"key 'units\.position': expected .*, found 'deg'"):
        decode_meta(encode_meta({**side, "units": {"effort": "N m", "position": "deg"}}))
    with pytest.raises(WireError, match=r"key 'sample_time': expected a value >= 0\.0001"):
        decode_meta(encode_meta({**side, "sample_time": -1}))
    # a minor-0 meta as an older publisher sends it (no minor, no axes) is still read
    old = json.dumps({"schema": "cutwatch.meta", "version": 1, **side}).encode()
    assert decode_meta(old)["kind"] == "two_inertia"
    with pytest.raises(WireError, match="sample_time expected a number > 0"):
        decode_meta(
            json.dumps({"schema": "cutwatch.meta", "version": 1, **side, "sample_time": 0}).encode()
        )


# --- minor version 1: the CNC's identities (program, segments of tool / line / override)


def test_identities_round_trip_and_expand_per_sample() -> None:
    from server.records.drive_wire import MINOR, Segment

    cols = block(100)
    segs = [Segment(0, 1, 20, 1.0), Segment(60, 2, 30, 1.2)]
    b = decode_drive(encode_drive(3, 0.5, 2e-4, cols, UNITS, program="O1001", segments=segs))
    assert (b.minor, b.program, b.segments) == (MINOR, "O1001", tuple(segs))
    ident = b.identities()
    assert ident is not None
    np.testing.assert_array_equal(ident["tool"], [1] * 60 + [2] * 40)
    np.testing.assert_array_equal(ident["line"], [20] * 60 + [30] * 40)
    np.testing.assert_array_equal(ident["override"], [1.0] * 60 + [1.2] * 40)


def test_an_old_publisher_without_minor_is_still_accepted() -> None:
    payload = encode_drive(0, 0.0, 4e-4, block(10), UNITS)
    head = json.loads(payload.split(b"\n", 1)[0])
    assert "minor" not in head and "segments" not in head
    b = decode_drive(payload)
    assert (b.minor, b.program, b.segments, b.identities()) == (0, None, (), None)


def test_an_old_receiver_reads_a_new_block() -> None:
    """A minor-0 receiver reads only the keys it knows: the columns are unchanged."""
    from server.records.drive_wire import Segment

    new = encode_drive(0, 0.0, 4e-4, block(10), UNITS, program="O7", segments=[Segment(0, 1, 5)])
    head, body = new.split(b"\n", 1)
    h = json.loads(head)
    old_keys = {"schema", "version", "seq", "t0", "sample_time", "n", "columns"}
    assert h["version"] == 1 and old_keys <= set(h)
    old = json.dumps({k: h[k] for k in old_keys}).encode() + b"\n" + body
    assert decode_drive(old).columns.keys() == decode_drive(new).columns.keys()


@pytest.mark.parametrize(
    ("changes", "kind", "match"),
    [
        ({"minor": 1, "program": ""}, "schema", "program"),
        ({"minor": 1, "program": "x" * 33}, "schema", "program"),
        ({"minor": 1, "segments": {"i": 0}}, "schema", "segments expected a list"),
        ({"minor": 1, "segments": [{"i": 0, "tool": 1}]}, "schema", r"segments\[0\].line"),
        ({"minor": 1, "segments": [{"i": 2, "tool": 1, "line": 1}]}, "shape", r"segments\[0\].i"),
        (
            {
                "minor": 1,
                "segments": [{"i": 0, "tool": 1, "line": 1}, {"i": 0, "tool": 1, "line": 2}],
            },
            "shape",
            r"segments\[1\].i",
        ),
        (
            {"minor": 1, "segments": [{"i": 0, "tool": 1, "line": 1, "override": 0}]},
            "value",
            "override",
        ),
        ({"minor": -1}, "version", "minor"),
    ],
)
def test_malformed_identities_are_named(changes: dict, kind: str, match: str) -> None:
    payload = _with_header(encode_drive(0, 0.0, 4e-4, block(10), UNITS), **changes)
    with pytest.raises(WireError, match=match) as exc:
        decode_drive(payload)
    assert exc.value.kind == kind


# --- minor 2: every column of a machine; meta minor 1: the machine description


def _machine() -> dict:
    return {
        "sample_time": 2e-3,
        "axes": {
            "X": {"kind": "rigid", "signals": {"q_m": "X_q", "i_m": "X_i", "qd_m": "X_v"},
                  "units": {"position": "m"}},
            "Y": {"kind": "rigid", "signals": {"q_m": "Y_q", "tau_m": "Y_f", "f_ext": "Y_ref"},
                  "units": {"position": "m", "effort": "N"}},
        },
        "spindle": {"signals": {"speed": "S_n", "load": "S_load"}},
        "identities": {"tool": "T", "line": "N"},
    }  # fmt: skip


def _centre_block(n: int = 50, extra: bool = True) -> bytes:
    rng = np.random.default_rng(1)
    cols = {
        "X_q": np.cumsum(rng.normal(size=n)) * 1e-5,
        "X_i": rng.normal(size=n),
        "X_v": rng.normal(size=n),
        "Y_q": np.cumsum(rng.normal(size=n)) * 1e-5,
        "Y_f": rng.normal(size=n) * 50,
        "S_n": np.full(n, 8000.0),
        "S_load": np.full(n, 35.0),
    }
    units = {"X_q": "m", "X_i": "A", "X_v": "m/s", "Y_q": "m", "Y_f": "N"}
    units |= {"S_n": "rpm", "S_load": "%"}
    if extra:  # what this receiver's machine does not name: a temperature, a voltage
        cols |= {"X_temp": np.full(n, 41.0), "Y_volt": np.full(n, 560.0)}
        units |= {"X_temp": "", "Y_volt": ""}
    from server.records.drive_wire import Segment

    return encode_drive(4, 0.2, 2e-3, cols, units, segments=[Segment(0, 3, 120)])


def test_a_machine_block_travels_every_column_and_unknown_ones_are_ignored_not_fatal() -> None:
    from common.machine_description import from_dict
    from server.records.drive_wire import MINOR, check_block

    b = decode_drive(_centre_block())
    assert b.minor == MINOR == 2 and b.n == 50 and len(b.columns) == 9
    checked = check_block(b, from_dict(_machine()))
    assert checked.ignored == ("X_temp", "Y_volt")
    assert set(checked.columns) == {"X_q", "X_i", "X_v", "Y_q", "Y_f", "Y_ref", "S_n", "S_load"}
    # an optional signal the block lacks is NaN, so every block has the machine's columns
    assert np.isnan(checked.columns["Y_ref"]).all()
    np.testing.assert_array_equal(checked.columns["S_n"], 8000.0)
    assert b.identities() is not None and (b.identities() or {})["tool"][0] == 3


@pytest.mark.parametrize(
    ("change", "kind", "match"),
    [
        (("drop", "Y_f"), "shape", r"'Y_f' \(Y.tau_m\): missing"),
        (("unit", "X_v", "rad/s"), "units", r"'X_v' \(X.qd_m\): unit expected 'm/s'"),
        (("unit", "S_n", "1/s"), "units", r"'S_n' \(spindle.speed\): unit expected 'rpm'"),
        (("nan", "X_q"), "value", r"'X_q' \(X.q_m\): non-finite"),
    ],
)
def test_a_machine_block_that_breaks_its_description_is_named(
    change: tuple, kind: str, match: str
) -> None:
    from common.machine_description import from_dict
    from server.records.drive_wire import check_block

    b = decode_drive(_centre_block())
    cols, units = dict(b.columns), dict(b.units)
    if change[0] == "drop":
        del cols[change[1]]
    elif change[0] == "unit":
        units[change[1]] = change[2]
    else:
        cols[change[1]] = cols[change[1]].copy()
        cols[change[1]][3] = np.nan
    bad = decode_drive(encode_drive(0, 0.0, 2e-3, cols, units))
    with pytest.raises(WireError, match=match) as err:
        check_block(bad, from_dict(_machine()))
    assert err.value.kind == kind


def test_a_non_finite_optional_signal_travels() -> None:
    from common.machine_description import from_dict
    from server.records.drive_wire import check_block

    b = decode_drive(_centre_block())
    cols = dict(b.columns)
    cols["S_load"] = np.full(b.n, np.nan)  # the spindle's load not known for this block
    out = check_block(
        decode_drive(encode_drive(0, 0.0, 2e-3, cols, b.units)), from_dict(_machine())
    )
    assert np.isnan(out.columns["S_load"]).all()


def test_an_old_publishers_block_with_an_extra_column_is_kept() -> None:
    """Before minor 2 a block with any unknown column was refused whole."""
    from common.machine_description import from_legacy
    from server.records.drive_wire import check_block

    payload = encode_drive(0, 0.0, 4e-4, block(10), UNITS)
    head, body = payload.split(b"\n", 1)
    h = json.loads(head)
    h["columns"].append({"name": "temperature", "dtype": "<f8", "unit": ""})
    b = decode_drive(json.dumps(h).encode() + b"\n" + body + np.zeros(10).tobytes())
    m = from_legacy({"sample_time": 4e-4, "units": UNITS, "kind": "two_inertia"})
    out = check_block(b, m)
    assert out.ignored == ("temperature",) and set(out.columns) == {"tau_m", "q_m", "q_l", "f_ext"}


def test_unknown_units_and_names_are_refused_when_encoding() -> None:
    with pytest.raises(WireError, match="unit expected one of") as err:
        encode_drive(0, 0.0, 1e-3, {"X_q": np.zeros(3)}, {"X_q": "mm"})
    assert err.value.kind == "units"
    with pytest.raises(WireError, match="without ,"):
        encode_drive(0, 0.0, 1e-3, {"a,b": np.zeros(3)}, {"a,b": "m"})


def test_the_meta_carries_the_machine_description_as_minor_1() -> None:
    from common.machine_description import from_dict
    from server.records.drive_wire import META_MINOR, machine_of

    d = decode_meta(encode_meta({**_machine(), "program": "O1"}))
    assert d["minor"] == META_MINOR == 1 and "units" not in d  # no legacy keys: 2 axes
    assert machine_of(d) == from_dict(_machine())
    bad = _machine()
    bad["axes"]["X"]["units"]["position"] = "mm"
    with pytest.raises(WireError, match=r"key 'axes.X.units.position'") as err:
        encode_meta(bad)
    assert err.value.kind == "units"
    raw = json.dumps({"schema": "cutwatch.meta", "version": 1, "minor": 1, **bad}).encode()
    with pytest.raises(WireError, match=r"key 'axes.X.units.position'"):
        decode_meta(raw)


def test_a_one_axis_meta_stays_readable_by_an_older_receiver() -> None:
    """A single axis with the old column names also gets the minor-0 keys."""
    from server.records.drive_wire import machine_of

    side = {"sample_time": 1e-3, "units": {"effort": "A", "position": "m"}, "kind": "rigid",
            "nominal": {"K_t": 20.0}}  # fmt: skip
    d = decode_meta(encode_meta(side))
    assert d["units"] == {"effort": "A", "position": "m"} and d["nominal"] == {"K_t": 20.0}
    assert d["kind"] == "rigid" and d["axes"]["axis"]["signals"]["i_m"] == "i_m"
    assert machine_of(d).axes[0].K_t == 20.0
