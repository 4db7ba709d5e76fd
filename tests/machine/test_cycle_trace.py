"""A CNC's trace: a point sample per cycle or the cycle's average."""

from __future__ import annotations

import numpy as np
import pytest

from machine.cycle_trace import trace
from machine.errors import ParameterError


def test_point_and_average() -> None:
    t = np.arange(12) * 2e-4
    x = np.arange(12.0)
    p = trace({"t": t, "x": x}, 4, "point")
    a = trace({"t": t, "x": x}, 4, "average")
    np.testing.assert_array_equal(p["x"], [3.0, 7.0, 11.0])  # the cycle's tick
    np.testing.assert_array_equal(a["x"], [1.5, 5.5, 9.5])  # the cycle's mean
    np.testing.assert_allclose(np.diff(p["t"]), 8e-4)
    np.testing.assert_allclose(a["t"], [3e-4, 11e-4, 19e-4])  # the cycle's middle


def test_the_average_damps_what_the_point_sample_aliases() -> None:
    """402 Hz seen at 500 Hz: the point sample keeps its amplitude at 98 Hz, the cycle's
    average (10 samples of 5 kHz) damps it by its sinc."""
    ts = 2e-4
    t = np.arange(50_000) * ts
    x = np.sin(2 * np.pi * 402.0 * t)
    p = trace({"x": x}, 10, "point")["x"]
    a = trace({"x": x}, 10, "average")["x"]
    assert np.std(p) == pytest.approx(np.sqrt(0.5), rel=0.05)
    damp = abs(np.sinc(402.0 * 10 * ts) / np.sinc(402.0 * ts))
    assert np.std(a) == pytest.approx(np.sqrt(0.5) * damp, rel=0.1)


def test_bad_input_is_named() -> None:
    with pytest.raises(ParameterError, match="model"):
        trace({"x": np.zeros(4)}, 2, "mean")
    with pytest.raises(ParameterError, match="multiple of 3"):
        trace({"x": np.zeros(4)}, 3, "point")
    with pytest.raises(ParameterError, match="factor"):
        trace({"x": np.zeros(4)}, 0, "point")
