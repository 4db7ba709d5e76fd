"""The nested evaluation of issue 35 on the real turning-wear table: splits, knots, and
that nothing of a test tool's VB reaches the choice, the fit or the interval."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from server.pipeline import wear_nested as W

DATA = next(
    (
        p / "shared" / "data" / "turning-wear" / "segments.csv"
        for p in Path(__file__).resolve().parents
        if (p / "shared" / "data" / "turning-wear" / "segments.csv").exists()
    ),
    None,
)
pytestmark = pytest.mark.skipif(DATA is None, reason="turning-wear data not present")


@pytest.fixture(scope="module")
def table() -> W.WearTable:
    return W.load(DATA, ["F_f"])


def test_outer_splits_are_loto_then_ten_distinct_draws_of_each_k(table: W.WearTable) -> None:
    sp = W.outer_splits(table.tools)
    assert [t for p, t in sp if p == "loto"] == [(t,) for t in table.tools]
    for k in W.K_OUT:
        draws = [t for p, t in sp if p == f"l{k}o"]
        assert len(draws) == W.SPLITS_PER_K == len(set(draws))
        assert all(len(d) == k for d in draws)
    assert sp == W.outer_splits(table.tools)  # seeded


def test_knots_are_the_measured_points(table: W.WearTable) -> None:
    for t in table.tools:
        vb = table.column(W.VB, t)
        k = W.knots(vb)
        assert 4 <= len(k) <= 10, (t, len(k))
        # between knots VB is a straight line (the file interpolates linearly)
        full = np.interp(np.arange(len(vb)), k, vb[k])
        assert np.max(np.abs(full - vb)) < 0.5


def test_a_test_tools_vb_reaches_nothing_but_the_score(table: W.WearTable) -> None:
    """Doubling the test tool's VB changes neither the chosen configuration, nor the
    estimate, nor its interval, nor any baseline (all fitted inside the fold)."""
    cfgs = [c for c in W.candidates() if c.map != "gbr"]
    a = W.run_fold(table, "F_f", (16,), "loto", W._Cache(), configs=cfgs)
    cols = dict(table.columns)
    rows = table.rows_of(16)
    vb = cols[W.VB].copy()
    vb[rows] *= 2.0
    cols[W.VB] = vb
    other = dataclasses.replace(table, columns=cols)
    b = W.run_fold(other, "F_f", (16,), "loto", W._Cache(), configs=cfgs)
    assert a.chosen == b.chosen
    ta, tb = a.tools[0], b.tools[0]
    np.testing.assert_allclose(ta.est, tb.est)
    np.testing.assert_allclose(ta.lo, tb.lo)
    np.testing.assert_allclose(ta.hi, tb.hi)
    for k in W.BASELINES:
        np.testing.assert_allclose(ta.base[k], tb.base[k])
    m = W.fold_metrics(a)
    assert 0 < m["mae"] < 200 and 0 <= m["coverage"] <= 1 and m["width"] > 0
    assert np.all(ta.lo <= ta.hi)
