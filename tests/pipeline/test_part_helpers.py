"""The per-block helpers of issue 32's cost cuts give numpy's numbers, bit for bit:
``nan_to_num`` (skipped on all-finite blocks), ``diff_from`` (``np.diff`` with a
``prepend``, without the concatenation), ``nan_channels`` (rows of one array), and the
pipeline's ``latest`` taken when asked for."""

from __future__ import annotations

import math

import numpy as np
import pytest

from server.pipeline.part import Channel, diff_from, nan_channels, nan_to_num

_CASES = [
    np.array([1.0, -0.0, 0.0, 2.5, -3.0]),
    np.array([1.0, math.nan, math.inf, -math.inf, -0.0]),
    np.array([math.nan]),
    np.zeros(0),
]


@pytest.mark.parametrize("a", _CASES)
def test_nan_to_num_is_numpys(a: np.ndarray) -> None:
    assert nan_to_num(a).tobytes() == np.nan_to_num(a, nan=0.0).tobytes()


def test_nan_to_num_of_a_finite_block_is_the_block() -> None:
    a = np.array([1.0, 2.0])
    assert nan_to_num(a) is a  # no copy: the callers only read it


@pytest.mark.parametrize("a", _CASES)
@pytest.mark.parametrize("prev", [0.0, -0.0, 1.5, math.nan])
def test_diff_from_is_numpys(a: np.ndarray, prev: float) -> None:
    want = np.diff(a, prepend=prev)
    got = diff_from(a, prev)
    assert got.shape == want.shape and got.tobytes() == want.tobytes()


def test_nan_channels_are_separate_nan_rows() -> None:
    chans = [Channel("a", "", "a", "g"), Channel("b", "", "b", "g")]
    out = nan_channels(chans, 5)
    assert list(out) == ["a", "b"] and all(
        np.isnan(v).all() and v.shape == (5,) for v in out.values()
    )
    out["a"][0] = 1.0  # a part writing into one channel does not touch another
    assert np.isnan(out["b"]).all()
    assert out["a"].flags.c_contiguous


def test_latest_is_the_last_value_of_each_channel() -> None:
    from server.experiments.benchmarks.bench_centre_pipeline import drive_blocks, pipeline_of
    from server.pipeline.live_pipeline import LivePipeline

    meta, blocks = drive_blocks(3.0)
    p = pipeline_of(meta, blocks)
    assert isinstance(p, LivePipeline)
    assert p.latest == {}
    for _ in range(5):
        out = p.step(50)
    want = {k: float(v[-1]) for k, v in out.items()}
    assert p.latest.keys() == want.keys()
    assert all((math.isnan(want[k]) and math.isnan(v)) or want[k] == v for k, v in p.latest.items())
    assert p.state().latest.keys() == want.keys()


def _same(a: dict[str, float], b: dict[str, float]) -> bool:
    return a.keys() == b.keys() and all(
        (math.isnan(a[k]) and math.isnan(b[k])) or a[k] == b[k] for k in a
    )


def test_a_step_during_a_read_never_masks_the_newer_block() -> None:
    """A worker's HTTP answer reads ``latest`` without the loop's lock. Here the loop steps
    while a reader is taking block k's values (the interleaving the review found: the
    reader then cleared block k+1's outputs and kept k's); the next read must give block
    k+1's. A restored state's values read back as they were set."""
    from server.experiments.benchmarks.bench_centre_pipeline import drive_blocks, pipeline_of

    meta, blocks = drive_blocks(3.0)
    p = pipeline_of(meta, blocks)
    for _ in range(3):
        p.step(50)
    stepped: list[dict[str, np.ndarray]] = []

    class SteppingOutputs(dict):  # type: ignore[type-arg]
        def items(self):  # type: ignore[no-untyped-def,override]
            if not stepped:
                stepped.append(p.step(50))  # the loop thread runs here
            return super().items()

    assert p._last_out is not None
    old = {k: float(v[-1]) for k, v in p._last_out.items()}
    p._last_out = SteppingOutputs(p._last_out)
    assert _same(p.latest, old)  # the racing read itself gives block k
    new = {k: float(v[-1]) for k, v in stepped[0].items()}
    assert not _same(old, new)
    assert _same(p.latest, new)
    p._last = {"a": 1.5, "b": math.nan}
    got = p.latest
    assert got["a"] == 1.5 and math.isnan(got["b"]) and got.keys() == {"a", "b"}


def test_column_or_gives_the_column_or_the_fill() -> None:
    from server.pipeline.part import column_or

    a = np.array([1.0, 2.0])
    assert column_or({"x": a}, "x", 2, math.nan) is a
    assert column_or({}, "x", 3, 1.0).tolist() == [1.0, 1.0, 1.0]
    assert np.isnan(column_or({}, "x", 2, math.nan)).all()
