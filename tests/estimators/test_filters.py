"""Discrete filters against their analytic (continuous) frequency response."""

import math

import numpy as np
import pytest
import scipy.signal as ss

from estimators.errors import ParameterError
from estimators.filters import discretize, highpass, lowpass


@pytest.mark.parametrize("order", [1, 2, 3])
@pytest.mark.parametrize("fc", [12.0, 40.0, 250.0])
def test_lowpass_matches_continuous_response(fc: float, order: int) -> None:
    ts = 4e-4
    f = lowpass(fc, ts, order)
    # pre-warped Tustin: exact at the cut-off
    wc = 2 * math.pi * fc
    h_cont = (wc / (1j * wc + wc)) ** order
    assert abs(f.response([fc])[0] - h_cont) < 1e-9
    # everywhere: the analogue response at the pre-warped frequency (Tustin's mapping)
    freqs = np.array([0.0, 0.1, 0.5, 2.0, 5.0]) * fc
    freqs = freqs[freqs < 0.5 / ts]
    k = wc / math.tan(wc * ts / 2)
    w_warp = k * np.tan(2 * np.pi * freqs * ts / 2)
    h_a = (wc / (1j * w_warp + wc)) ** order
    np.testing.assert_allclose(f.response(freqs), h_a, atol=1e-9)
    assert abs(f.response([0.0])[0] - 1.0) < 1e-9


def test_run_matches_scipy_lfilter_and_block_splitting() -> None:
    rng = np.random.default_rng(1)
    x = rng.normal(size=1000)
    f = lowpass(250.0, 4e-4, 2)
    y_ref = ss.lfilter(f.b, f.a, x)
    y1, z = f.run(x[:317])
    y2, _ = f.run(x[317:], z)
    np.testing.assert_allclose(np.concatenate([y1, y2]), y_ref, atol=1e-12)


def test_sine_through_filter_has_the_analytic_gain_and_phase() -> None:
    ts, fc, f0 = 4e-4, 250.0, 100.0
    f = lowpass(fc, ts, 1)
    t = np.arange(20000) * ts
    y, _ = f.run(np.sin(2 * np.pi * f0 * t))
    tail = slice(10000, None)
    c = 2 * np.mean(y[tail] * np.exp(-2j * np.pi * f0 * t[tail]))
    h = f.response([f0])[0]
    # the DFT of sin gives -j * H
    assert abs(c - (-1j) * h) < 1e-3


def test_highpass_blocks_dc() -> None:
    f = highpass(5.0, 1e-3)
    assert abs(f.response([0.0])[0]) < 1e-12
    assert abs(abs(f.response([5.0])[0]) - 1 / math.sqrt(2)) < 1e-9


def test_initial_state_is_steady() -> None:
    f = lowpass(40.0, 4e-4, 3)
    y, _ = f.run(np.full(10, 2.5), f.initial_state(2.5))
    np.testing.assert_allclose(y, 2.5, atol=1e-12)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"cutoff_hz": 1250.0, "sample_time": 4e-4}, "cutoff_hz.*below Nyquist"),
        ({"cutoff_hz": -1.0, "sample_time": 4e-4}, "cutoff_hz.*> 0"),
        ({"cutoff_hz": float("nan"), "sample_time": 4e-4}, "cutoff_hz"),
        ({"cutoff_hz": 10.0, "sample_time": 0.0}, "sample_time"),
        ({"cutoff_hz": 10.0, "sample_time": 4e-4, "order": 0}, "order.*integer >= 1"),
    ],
)
def test_bad_filter_parameters_are_named(kwargs: dict, match: str) -> None:
    with pytest.raises(ParameterError, match=match):
        lowpass(**kwargs)


def test_improper_transfer_function_refused() -> None:
    with pytest.raises(ParameterError, match="proper"):
        discretize([1.0, 0.0, 0.0], [1.0, 1.0], 1e-3)


def test_state_space_zoh_agrees_with_scipy() -> None:
    import scipy.linalg
    import scipy.signal

    from common.linalg import expm, zoh

    rng = np.random.default_rng(4)
    for scale in (1e-3, 0.3, 5.0, 300.0):
        m = rng.normal(size=(5, 5)) * scale
        ref = scipy.linalg.expm(m)
        np.testing.assert_allclose(expm(m), ref, rtol=1e-10, atol=1e-12 * np.abs(ref).max())
    f = np.array([[0.0, 1.0], [-400.0, -3.0]])
    g = np.array([0.0, 2.0])
    phi, gam = zoh(f, g, 1e-3)
    ad, bd, *_ = scipy.signal.cont2discrete((f, g[:, None], np.eye(2), np.zeros((2, 1))), 1e-3)
    np.testing.assert_allclose(phi, ad, rtol=1e-12)
    np.testing.assert_allclose(gam, bd[:, 0], rtol=1e-12)
