"""Every filter, observer and identifier designed from the rate it is given (issue 30):
the papers' design at 2.5 kHz, a design and no refusal anywhere from 10 Hz to 10 kHz,
and the load-side relation where the torsion lies above the Nyquist frequency."""

from __future__ import annotations

import numpy as np
import pytest

from estimators.force_observer import (
    ObserverParams,
    TorsionEstimator,
    observer_design,
    q_cutoff,
    torsion_frequencies,
)
from estimators.rls import IdentifierParams, LoadIdentifier
from estimators.segment_id import SegmentIdentifier, SegmentIdentifierParams
from machine.stage_params import preset

P = preset("seed000")


def test_at_2_5_khz_the_papers_design_is_unchanged() -> None:
    """seed 000 Table II: Q 250 Hz, Q_RLS 12 Hz, window 100 samples; the segment fit
    keeps every 10th sample."""
    o = ObserverParams(J_M=P.J_M, B_M=P.B_M, F_CM=P.F_CM, K=P.K, sample_time=4e-4)
    i = IdentifierParams(sample_time=4e-4)
    s = SegmentIdentifierParams(nominal=(P.J_L, P.B_L, P.F_CL), sample_time=4e-4)
    assert (o.q_hz, o.mix, i.q_rls_hz, i.window, s.decimation) == (
        250.0, "minimum_variance", 12.0, 100, 10,
    )  # fmt: skip
    assert observer_design(P.J_M, P.J_L, P.K, 4e-4) == ({"q_hz": 250.0}, "")


@pytest.mark.parametrize("rate", [10, 100, 500, 1000, 2500, 10_000])
def test_every_rate_has_a_design_that_runs(rate: int) -> None:
    ts = 1.0 / rate
    design, _ = observer_design(P.J_M, P.J_L, P.K, ts)
    front = TorsionEstimator(
        ObserverParams(J_M=P.J_M, B_M=P.B_M, F_CM=P.F_CM, K=P.K, sample_time=ts, **design)
    )
    ip = IdentifierParams(sample_time=ts)
    seg = SegmentIdentifier(SegmentIdentifierParams(nominal=(P.J_L, P.B_L, P.F_CL), sample_time=ts))
    assert 0 < front.params.q_hz < 0.5 * rate and 0 < ip.q_rls_hz < 0.5 * rate
    n = 50
    t = np.arange(n) * ts
    q = np.sin(2 * np.pi * 0.5 * t)
    _, rec = front.step(front.initial_state(), np.zeros(n), q, q)
    _, r = LoadIdentifier(ip).step(
        LoadIdentifier(ip).initial_state(P.J_L, P.B_L, P.F_CL), rec.t_s, rec.acc_l, rec.vel_l,
        rec.sgn_l, rec.omega_l,
    )  # fmt: skip
    _, g = seg.step(seg.initial_state(), t, rec.t_s, rec.acc_l, rec.vel_l, rec.sgn_l)
    assert r.theta.shape == (n, 4) and g.theta.shape == (n, 3)


def test_below_the_torsion_the_load_side_relation_only() -> None:
    f_res, f_anti = torsion_frequencies(P.J_M, P.J_L, P.K)
    assert (round(f_res), round(f_anti)) == (404, 285)  # the 402 / 285 Hz
    design, why = observer_design(P.J_M, P.J_L, P.K, 2e-3)
    assert design == {"q_hz": 200.0, "mix": "twist"}
    assert "404 Hz resonance" in why and "Nyquist frequency 250 Hz" in why
    assert observer_design(P.J_M, P.J_L, P.K, 1e-3)[1] == ""  # 1 kHz: 500 Hz Nyquist
    assert q_cutoff(2e-3) == 200.0 and q_cutoff(1e-4) == 250.0


def test_the_load_side_relation_is_the_shafts_twist() -> None:
    ts = 2e-3
    front = TorsionEstimator(ObserverParams(J_M=P.J_M, B_M=P.B_M, F_CM=P.F_CM, K=P.K,
                                            sample_time=ts, mix="twist"))  # fmt: skip
    rng = np.random.default_rng(0)
    qm, ql = rng.normal(size=40).cumsum(), rng.normal(size=40).cumsum()
    _, rec = front.step(front.initial_state(), rng.normal(size=40), qm, ql)
    np.testing.assert_array_equal(rec.alpha, 0.0)
    np.testing.assert_array_equal(rec.t_s, rec.t_sk)
