"""The centre's wear estimator on readings drawn from its own measurement model, over many
seeds: it follows the wear, its 95 % interval covers, a new instance ends a life, a
label calibrates the map, bad labels are named."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimators.errors import ParameterError
from estimators.wear.centre import CentreWear, CentreWearParams

KEY = (2, "O2001", 140)
REF_W = 1000.0


def _life(rng: np.random.Generator, gain: float, n: int = 60, life_s: float = 300.0):
    """(seconds per execution, true VB per execution [m], mean power per execution [W]):
    a three-phase wear curve like a milling cutter's, readings z = gain (VB - VB_t)."""
    dt = life_s / n
    t = dt * np.arange(1, n + 1)
    x = t / life_s
    vb = 0.05e-3 * (1 - np.exp(-x / 0.03)) + 0.18e-3 * x + 0.07e-3 * x**6
    vb_t = float(np.mean(vb[:3]))
    z = gain * (vb - vb_t) + 0.02 * rng.standard_normal(n)
    return dt, vb, REF_W * (1 + z)


def _run(w: CentreWear, st, dt, vb, power, t0=0.0):
    est, lo, hi = [], [], []
    for k in range(len(vb)):
        st, _ = w.observe(st, KEY, float(power[k]), dt, t0 + (k + 1) * dt)
        e = w.estimate(st, KEY[0])
        est.append(e["vb"]), lo.append(e["lo"]), hi.append(e["hi"])
    return st, np.array(est), np.array(lo), np.array(hi)


def test_uncalibrated_follows_the_wear_and_covers_over_seeds() -> None:
    """40 seeds, each its own gain (0.6-3x the prior's median): the prior's interval
    covers the truth on >= 90 % of the read executions pooled."""
    w = CentreWear()
    cov, err = [], []
    for seed in range(40):
        rng = np.random.default_rng(seed)
        a0 = w.params.rise_at_limit / (w.params.vb_limit - w.params.vb_taught)
        gain = a0 * float(np.exp(rng.uniform(np.log(0.6), np.log(2.0))))
        dt, vb, p = _life(rng, gain)
        _, est, lo, hi = _run(w, w.initial_state(), dt, vb, p)
        k = slice(w.params.teach, None)
        cov.append(np.mean((vb[k] >= lo[k]) & (vb[k] <= hi[k])))
        err.append(np.mean(np.abs(est[k] - vb[k])))
    assert np.mean(cov) >= 0.9, np.mean(cov)
    assert np.median(err) < 0.1e-3  # a third of the limit, uncalibrated


def test_a_label_calibrates_the_map_and_narrows_the_interval() -> None:
    """Life 1 ends (a fresh instance's readings), its measured VB is entered; life 2 is
    then read with the labelled gain: smaller error and width than uncalibrated, over
    20 seeds."""
    w = CentreWear()
    better, narrower, cov = [], [], []
    for seed in range(20):
        rng = np.random.default_rng(100 + seed)
        gain = 2.5 / 0.3e-3 * float(np.exp(0.1 * rng.standard_normal()))
        dt, vb, p = _life(rng, gain)
        st, est_u, lo_u, hi_u = _run(w, w.initial_state(), dt, vb, p)
        assert not w.estimate(st, 2)["calibrated"]
        # a new instance: two readings back at the fresh level end the life
        t = len(vb) * dt
        for j in range(2):
            st, r = w.observe(st, KEY, REF_W * (1 + 0.01 * rng.standard_normal()), dt,
                              t + (j + 1) * dt)  # fmt: skip
        assert r.kind == "changed" and len(st.lives) == 1
        assert st.tools[2].instance == 2 and st.tools[2].x[0] < 0.02e-3
        life = w.label(st, 2, float(vb[-1]))
        assert life.labelled == pytest.approx(vb[-1])
        assert w.estimate(st, 2)["calibrated"]
        # the new instance wears as the first; its readings are against the first's
        # taught reference (VB_t: the first instance's mean VB while teaching)
        dt2, vb2, _ = _life(rng, gain)
        p2 = REF_W * (1 + gain * (vb2 - np.mean(vb[:3])) + 0.02 * rng.standard_normal(len(vb2)))
        st, est_c, lo_c, hi_c = _run(w, st, dt2, vb2, p2, t0=t + 2 * dt)
        k = slice(w.params.teach, None)
        better.append(np.mean(np.abs(est_c[k] - vb2[k])) < np.mean(np.abs(est_u[k] - vb[k])))
        narrower.append(np.median(hi_c - lo_c) < np.median(hi_u - lo_u))
        cov.append(np.mean((vb2[k] >= lo_c[k]) & (vb2[k] <= hi_c[k])))
    assert np.mean(narrower) == 1.0
    assert np.mean(better) >= 0.8
    assert np.mean(cov) >= 0.85


def test_the_state_never_shrinks_its_rate_and_an_override_is_not_read() -> None:
    w = CentreWear()
    st = w.initial_state()
    rng = np.random.default_rng(7)
    dt, vb, p = _life(rng, 2.0 / 0.3e-3)
    for k in range(len(vb)):
        st, r = w.observe(st, KEY, float(p[k]), dt, (k + 1) * dt)
        assert st.tools[2].x[1] >= 0.0
    before = st.tools[2].x.copy()
    st, r = w.observe(st, KEY, 2 * REF_W, dt, 1e3, override=0.8)
    assert r.kind == "skipped" and np.array_equal(st.tools[2].x, before)
    # a block under the cut threshold (air) is taught but never read
    air = (2, "O2001", 30)
    for k in range(5):
        st, r = w.observe(st, air, 5.0, 1.0, 2e3 + k)
    assert r.kind == "skipped"


def test_labels_are_refused_with_the_field_named() -> None:
    w = CentreWear()
    st = w.initial_state()
    with pytest.raises(ParameterError, match="tool"):
        w.label(st, 2, 0.3e-3)
    with pytest.raises(ParameterError, match="vb"):
        w.label(st, 2, -1.0)
    with pytest.raises(ParameterError, match="vb"):
        w.label(st, 2, math.nan)
    with pytest.raises(ParameterError, match="teach"):
        CentreWearParams(teach=0)
