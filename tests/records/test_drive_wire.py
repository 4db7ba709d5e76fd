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
    with pytest.raises(WireError, match=r"units\.position got 'deg'"):
        decode_meta(encode_meta({**side, "units": {"effort": "N m", "position": "deg"}}))
    with pytest.raises(WireError, match="sample_time expected a number > 0"):
        decode_meta(encode_meta({**side, "sample_time": -1}))
