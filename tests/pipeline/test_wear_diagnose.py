"""The diagnosis of issue 35's remaining misses on the real turning-wear table (quick:
tools 7 and 16 left out, the first list without boosting): what the knots allow, the
in-sample oracles, the per-tool shares, and that the held-out tool's VB reaches no
out-of-fold estimate."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from _shared_data import TURNING_WEAR, shared_file

from estimators.wear.hybrid import candidates, fit
from server.pipeline import wear_diagnose as D
from server.pipeline import wear_nested as W

DATA = shared_file(*TURNING_WEAR)
pytestmark = pytest.mark.skipif(DATA is None, reason="turning-wear data not present")
QUICK = [c for c in candidates(revision=1) if c.map != "gbr"]


@pytest.fixture(scope="module")
def table() -> W.WearTable:
    return W.load(DATA, ["F_f"])


@pytest.fixture(scope="module")
def folds(table: W.WearTable) -> list[W.FoldResult]:
    return D.loto_folds(table, "F_f", [7, 16], configs=QUICK)


@pytest.fixture(scope="module")
def diag(table: W.WearTable, folds: list[W.FoldResult]) -> dict[str, Any]:
    return D.diagnose(table, "F_f", folds, QUICK)


def test_the_chosen_configuration_refitted_is_the_folds_model(
    table: W.WearTable, folds: list[W.FoldResult], diag: dict[str, Any]
) -> None:
    """The map alone (``ours_map``) comes from the fold's chosen configuration refitted
    on the fold's training tools: filtered, it gives the fold's estimate again."""
    for f, t in zip(folds, diag["tools"], strict=True):
        cfg = D.chosen_config(f, QUICK)
        assert cfg.rate_law == f.rate_law and f.chosen.startswith(cfg.label + "/life=")
        train = [W.tool_data(table, ("F_f",), u) for u in table.tools if u not in f.test]
        m = fit(train, cfg)
        d = W.tool_data(table, ("F_f",), f.test[0])
        np.testing.assert_allclose(m.run(d)[0], f.tools[0].est, atol=1e-9)
        np.testing.assert_allclose(m.measure(m.inputs(d), d.feed), t["series"]["ours_map"])
        assert t["ours_map_mae"] != pytest.approx(t["ours_mae"])


def test_the_knots_band_and_the_smooth_curve(table: W.WearTable) -> None:
    """PCHIP passes through every measured point, never falls, and stays in the band
    between its knots; the band is the measured VB at a knot and spans the two knots'
    VB between them (so the file's straight line lies inside it)."""
    for t in table.tools:
        vb = table.column(W.VB, t)
        ip = D.interpolation(vb)
        kn = ip["knots"].astype(int)
        np.testing.assert_allclose(ip["pchip"][kn], vb[kn], atol=1e-9)
        assert np.all(np.diff(ip["pchip"]) >= -1e-9), t
        assert np.all(ip["lo"] - 1e-9 <= ip["pchip"]) and np.all(ip["pchip"] <= ip["hi"] + 1e-9)
        assert np.all((ip["lo"] - 1e-9 <= vb) & (vb <= ip["hi"] + 1e-9))
        np.testing.assert_array_equal(ip["lo"][kn], ip["hi"][kn])
        assert float(np.max(ip["hi"] - ip["lo"])) > 0.0


def test_the_band_on_a_made_up_life() -> None:
    """Knots at 0, 4, 8 (VB 0, 40, 40): between 0 and 4 the band is [0, 40], between
    the two equal knots it is a point."""
    vb = np.array([0.0, 10, 20, 30, 40, 40, 40, 40, 40])
    ip = D.interpolation(vb)
    assert ip["knots"].tolist() == [0, 4, 8]
    np.testing.assert_array_equal(ip["lo"], [0, 0, 0, 0, 40, 40, 40, 40, 40])
    np.testing.assert_array_equal(ip["hi"], [0, 40, 40, 40, 40, 40, 40, 40, 40])


def test_lower_bound_knots_and_shares_add_up(table: W.WearTable, diag: dict[str, Any]) -> None:
    p = diag["pooled"]
    assert [t["tool"] for t in diag["tools"]] == [7, 16]
    for m in D.METHODS:
        # the bound is the distance to the nearest edge of the band between the knots,
        # and the file's straight line lies inside the band: it is below the MAE
        assert 0.0 <= p[f"{m}_mae_lb"] <= p[f"{m}_mae"]
        assert p[f"{m}_mae"] == pytest.approx(sum(t[f"{m}_share"] for t in diag["tools"]))
        n_in, n_end = p["knots"] - 4, 4  # two tools: their first and last rows are ends
        both = p[f"{m}_mae_inner_knots"] * n_in + p[f"{m}_mae_ends"] * n_end
        assert p[f"{m}_mae_knots"] == pytest.approx(both / p["knots"])
        for t in diag["tools"]:
            s = t["series"]
            vb, e = np.array(s["vb"]), np.array(s[m])
            kn = W.knots(vb)
            assert t[f"{m}_mae_knots"] == pytest.approx(float(np.mean(np.abs(e - vb)[kn])))
            assert t[f"{m}_mae_lb"] <= t[f"{m}_mae"] + 1e-9
    assert diag["ratio_to_linear"]["mae"] == pytest.approx(p["ours_mae"] / p["linear_mae"])
    assert diag["beats_linear"] == sum(t["ours_mae"] < t["linear_mae"] for t in diag["tools"])
    assert diag["beats_linear_by"]["mae"] == diag["beats_linear"]
    for k in ("mae_knots", "mae_pchip", "mae_lb"):
        n = sum(t[f"ours_{k}"] < t[f"linear_{k}"] for t in diag["tools"])
        assert diag["beats_linear_by"][k] == n


def test_in_sample_oracles_bound_the_held_out_maps(diag: dict[str, Any]) -> None:
    """The line fitted on the tool itself is the least-squares line on its own rows: its
    error is below the held-out line's on every tool; boosting in-sample memorises."""
    for t in diag["tools"]:
        assert t["linear_oracle"] < t["linear_mae"]
        assert t["gbr5_oracle"] < 5.0 < t["gbr5_mae"]
        assert 0.0 < t["ours_oracle"] < 100.0 and 0.0 < t["ours_shared"] < 100.0
        assert t["gbr5_shared"] < t["gbr5_mae"]  # the tool in the fit
        assert 0.0 <= t["r2_mean"] <= t["r2_five_linear"] <= 1.0


def test_a_worn_tools_oracle_and_its_flat_reference(table: W.WearTable) -> None:
    """Tool 14 came in worn (41 um): no fresh segments to fit a reference from, so the
    oracle gives a flat one; any flat level gives the same estimate (the standardisation
    removes a constant)."""
    d = W.tool_data(table, ("F_f",), 14)
    assert d.vb is not None and d.vb[0] > 30.0
    cfg = W.HybridConfig("conditions", "isotonic", 1e-4, False, "mean")
    out = D.oracle(table, "F_f", d, cfg)
    assert set(out) == {"ours", "ours_map", "linear", "gbr5", "gbr_mean"}
    ref2 = np.array([[123.0], [0.0]])
    again = fit([d, d], cfg, ref_level=ref2).run(d)[0]
    np.testing.assert_allclose(out["ours"], again, atol=1e-6)
    assert float(np.mean(np.abs(out["ours"] - d.vb))) < float(np.ptp(d.vb)) / 4


def test_boosting_on_the_mean_sees_no_test_vb(table: W.WearTable) -> None:
    """``gbr_mean`` is fitted on the training tools' rows only: doubling the test tool's
    VB leaves it unchanged."""
    train = [t for t in table.tools if t != 16]
    a = D.gbr_mean(table, "F_f", train, 16)
    cols = dict(table.columns)
    vb = cols[W.VB].copy()
    vb[table.rows_of(16)] *= 2.0
    cols[W.VB] = vb
    b = D.gbr_mean(dataclasses.replace(table, columns=cols), "F_f", train, 16)
    np.testing.assert_allclose(a, b)
    assert len(a) == len(table.rows_of(16)) and np.ptp(a) > 50.0
    sk = D.gbr_mean(table, "F_f", train, 16, extra="SK")  # the _MEAN and the skewness
    assert not np.allclose(sk, a)


def test_one_more_feature_and_its_correlation(table: W.WearTable, diag: dict[str, Any]) -> None:
    p = diag["pooled"]
    for f in ("RMS", "MAX", "SK", "KURT"):
        per = [t[f"gbr_mean_{f}_sum"] for t in diag["tools"]]
        assert p[f"gbr_mean_{f}_mae"] == pytest.approx(sum(per) / p["rows"]) and min(per) > 0
        for t in diag["tools"]:
            x, vb = table.column(f"F_f_{f}", t["tool"]), table.column(W.VB, t["tool"])
            assert t[f"corr_{f}"] == pytest.approx(float(np.corrcoef(x, vb)[0, 1]))
    assert "+SK" in D.text(diag)


def test_text_and_figure(tmp_path: Path, diag: dict[str, Any]) -> None:
    s = D.text(diag)
    for m in D.METHODS:
        assert m in s
    assert "tool  7" in s and "tool 16" in s and "lower bound" in s
    D.figure([diag, diag], tmp_path / "d.png")
    assert (tmp_path / "d.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_fold_that_chose_the_offset_state_is_checked_without_it(table: W.WearTable) -> None:
    """When the fold's choice has the tool-offset state, the same configuration without
    it is run beside (the mechanism's check); the fold's own estimate is unchanged."""
    cfg = W.HybridConfig("conditions", "linear", 1e-4, True, "mean")
    (f,) = D.loto_folds(table, "F_f", [11], configs=[cfg])
    dg = D.diagnose(table, "F_f", [f], [cfg])
    (t,) = dg["tools"]
    train = [W.tool_data(table, ("F_f",), u) for u in table.tools if u != 11]
    d = W.tool_data(table, ("F_f",), 11)
    plain = fit(train, dataclasses.replace(D.chosen_config(f, [cfg]), offset=False)).run(d)[0]
    assert d.vb is not None
    assert t["ours_without_offset_mae"] == pytest.approx(float(np.mean(np.abs(plain - d.vb))))
    assert t["ours_without_offset_mae"] != pytest.approx(t["ours_mae"])
    np.testing.assert_allclose(t["series"]["ours"], f.tools[0].est)
    assert "without it" in D.text(dg)


def test_the_ratio_per_split_and_its_spread(
    table: W.WearTable, folds: list[W.FoldResult], diag: dict[str, Any]
) -> None:
    """Leave one out: one tool per split, so each split's ratio is that tool's; a split
    of two tools pools their rows (not the mean of their ratios)."""
    sp = D.spread(table, "F_f", folds, QUICK)
    ratios = [t["ours_mae"] / t["linear_mae"] for t in diag["tools"]]
    lo = sp["loto"]["ratio_mae"]
    assert lo["splits"] == 2 and lo["median"] == pytest.approx(float(np.median(ratios)))
    assert lo["min"] == pytest.approx(min(ratios)) and lo["max"] == pytest.approx(max(ratios))
    two = W.run_fold(table, "F_f", (7, 16), "l2o", W._Cache(), configs=QUICK)
    r = D.split_ratios(table, "F_f", two, QUICK)
    vb = np.concatenate([t.vb for t in two.tools])
    est = np.concatenate([t.est for t in two.tools])
    lin = np.concatenate([t.base["linear"] for t in two.tools])
    assert r["ours_mae"] == pytest.approx(float(np.mean(np.abs(est - vb))))
    assert r["ratio_mae"] == pytest.approx(r["ours_mae"] / float(np.mean(np.abs(lin - vb))))
    for k in D.SPLIT_KEYS:
        assert r[f"ours_{k}"] >= 0 and r[f"ratio_{k}"] > 0
    assert r["ours_mae_lb"] <= r["ours_mae"]
    assert "l2o (1 splits)" in D.spread_text(
        {"l2o": D.spread(table, "F_f", [two], QUICK)["l2o"]}, "F_f"
    )
