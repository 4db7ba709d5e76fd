"""rms: the one root mean square of every layer."""

from __future__ import annotations

import math

import numpy as np

from common.stats import rms


def test_rms_of_a_sine_and_of_constants() -> None:
    t = np.arange(10_000) / 10_000
    assert abs(rms(3.0 * np.sin(2 * np.pi * 5 * t)) - 3.0 / math.sqrt(2)) < 1e-12
    assert rms(np.full(7, -2.0)) == 2.0


def test_rms_of_nothing_is_nan_without_a_warning() -> None:
    assert math.isnan(rms(np.array([])))
