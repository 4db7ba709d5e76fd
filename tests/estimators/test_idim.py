"""IDIM-LS of a rigid axis: synthetic recovery, error paths, EMPS benchmark reproduction."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.io
from hypothesis import given, settings
from hypothesis import strategies as st

from estimators.errors import ParameterError
from estimators.idim import (
    IdimParams,
    decimate,
    decimated_index,
    idim_ls,
    kinematics,
    least_squares,
    rigid_regressor,
)

EMPS = Path(__file__).resolve().parents[3] / "shared" / "data" / "emps" / "DATA_EMPS.mat"
# Published IDIM-LS of the EMPS benchmark (Janot, Gautier, Brunot 2019; ../shared/data/README.md)
EMPS_PUBLISHED = {"M": 95.1089, "Fv": 203.5034, "Fc": 20.3935, "offset": -3.1648}
EMPS_RELERR = 4.08


def _synthetic(theta: tuple[float, float, float, float], n: int = 6000, ts: float = 1e-3):
    t = np.arange(n) * ts
    # smooth, band-limited motion with several reversals
    q = 0.05 * np.sin(2 * np.pi * 0.7 * t) + 0.02 * np.sin(2 * np.pi * 2.3 * t + 0.4)
    qd = 0.05 * 2 * np.pi * 0.7 * np.cos(2 * np.pi * 0.7 * t) + 0.02 * 2 * np.pi * 2.3 * np.cos(
        2 * np.pi * 2.3 * t + 0.4
    )
    qdd = -0.05 * (2 * np.pi * 0.7) ** 2 * np.sin(2 * np.pi * 0.7 * t) - 0.02 * (
        2 * np.pi * 2.3
    ) ** 2 * np.sin(2 * np.pi * 2.3 * t + 0.4)
    m, fv, fc, off = theta
    f = m * qdd + fv * qd + fc * np.sign(qd) + off
    return q, f, ts


def test_recovers_noise_free_rigid_parameters() -> None:
    theta = (12.0, 40.0, 5.0, -1.5)
    q, f, ts = _synthetic(theta)
    res = idim_ls(q, f, ts)
    # the decimation smooths sign(qd) in regressor and force alike: exact up to filtering
    np.testing.assert_allclose(res.theta, theta, rtol=2e-2, atol=0.05)
    assert res.relerr < 2.0
    assert res.names == ("M", "Fv", "Fc", "offset")


@given(
    m=st.floats(0.5, 200.0),
    fv=st.floats(0.0, 300.0),
    fc=st.floats(0.0, 30.0),
    off=st.floats(-10.0, 10.0),
)
@settings(max_examples=15, deadline=None)
def test_recovery_property(m: float, fv: float, fc: float, off: float) -> None:
    q, f, ts = _synthetic((m, fv, fc, off), n=3000)
    res = idim_ls(q, f, ts)
    kin = kinematics(q, ts)
    col_rms = np.sqrt(np.mean(rigid_regressor(kin.qd, kin.qdd) ** 2, axis=0))
    # each parameter's error, weighted by its column's size, is < 1 % of the effort's rms
    err = np.abs(res.theta - np.array([m, fv, fc, off])) * col_rms
    assert np.all(err <= 0.01 * np.sqrt(np.mean(f**2)) + 1e-6)


def test_extra_column_is_identified() -> None:
    q, f, ts = _synthetic((10.0, 30.0, 2.0, 0.0))
    extra = np.cos(2 * np.pi * q / 0.01)
    res = idim_ls(q, f + 3.0 * extra, ts, extra={"cos_q": extra})
    assert res.as_dict()["cos_q"] == pytest.approx(3.0, rel=0.05)


def test_decimate_keeps_last_sample_and_matches_index() -> None:
    x = np.arange(2005, dtype=float)
    p = IdimParams(decimation=10)
    idx = decimated_index(2005, p)
    assert idx[-1] == 2004
    assert len(decimate(x, p)) == len(idx)
    # a slow ramp passes the anti-alias filter up to its DC gain (even-order Chebyshev I
    # sits at the bottom of its 0.05 dB ripple at DC, twice: forward and backward)
    gain = 10 ** (-2 * 0.05 / 20)
    np.testing.assert_allclose(decimate(x, p)[30:-30], gain * x[idx][30:-30], rtol=1e-3)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"cutoff_hz": -1.0}, r"parameter 'cutoff_hz': expected a finite value > 0"),
        ({"order": 0}, r"parameter 'order': expected an integer in \[1, 12\]"),
        ({"decimation": 0}, r"parameter 'decimation': expected an integer in \[1, 1000\]"),
        ({"decimation_order": 20}, r"parameter 'decimation_order'"),
    ],
)
def test_bad_params_are_refused(kwargs: dict, match: str) -> None:
    with pytest.raises(ParameterError, match=match):
        IdimParams(**kwargs)


def test_bad_inputs_are_refused() -> None:
    with pytest.raises(ParameterError, match=r"'cutoff_hz': expected a value < Nyquist"):
        kinematics(np.zeros(100), 0.01, IdimParams(cutoff_hz=100.0))
    with pytest.raises(ParameterError, match=r"'q': expected more than 12 samples"):
        kinematics(np.zeros(5), 1e-3)
    with pytest.raises(ParameterError, match=r"'force': expected 100 samples, got 99"):
        idim_ls(np.zeros(100), np.zeros(99), 1e-3)
    with pytest.raises(ParameterError, match=r"'q': expected finite values"):
        idim_ls(np.full(100, np.nan), np.zeros(100), 1e-3)
    with pytest.raises(ParameterError, match=r"'regressor': expected full column rank 2"):
        least_squares(np.ones((10, 2)), np.ones(10), ("a", "b"))
    with pytest.raises(ParameterError, match=r"'samples': expected more than 2 samples"):
        least_squares(np.ones((2, 2)), np.ones(2), ("a", "b"))


@pytest.mark.skipif(not EMPS.exists(), reason="EMPS data not present")
def test_emps_idim_ls_reproduces_published_numbers_within_half_percent() -> None:
    d = scipy.io.loadmat(EMPS)
    t = d["t"].ravel()
    force = float(d["gtau"].ravel()[0]) * d["vir"].ravel()
    res = idim_ls(d["qm"].ravel(), force, float(np.median(np.diff(t))))
    for name, published in EMPS_PUBLISHED.items():
        ours = res.as_dict()[name]
        assert abs(ours - published) <= 0.005 * abs(published), (name, ours, published)
    # published to two decimals (4.08 %): ours must round to it within 0.01 point
    assert abs(res.relerr - EMPS_RELERR) <= 0.01
