"""`cutwatch reproduce turning-wear --quick --json`: its JSON shape and what the rows mean."""

from __future__ import annotations

import json

import pytest
from _shared_data import TURNING_WEAR, shared_file

from server.cli.main import main
from server.experiments.reproductions import turning_wear

pytestmark = pytest.mark.skipif(
    shared_file(*TURNING_WEAR) is None, reason="turning-wear data not present"
)


def test_quick_json_rows_and_checks(capsys: pytest.CaptureFixture) -> None:
    rc = main(["reproduce", "turning-wear", "--quick", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert out["experiment"] == "turning-wear"
    rows = {r["name"]: r for r in out["rows"]}
    for name in (
        "mae",
        "mae_gbr",
        "rmse",
        "coverage",
        "width_over_mae",
        "life_error_300um",
        "life_error_150um",
        "learning.n1.mae",
        "learning.n2.mae",
    ):
        assert f"feed_force.{name}" in rows, name
    for t in turning_wear.QUICK_TOOLS:
        r = rows[f"feed_force.tool.{t}.mae"]
        assert r["ours"] > 0 and r["paper"] > 0 and r["unit"] == "um"
        assert f"physics.tool.{t}.torque_per_feed_force" in rows
    # the pooled MAE lies between the per-tool ones; the width row is width / MAE
    per = [rows[f"feed_force.tool.{t}.mae"]["ours"] for t in turning_wear.QUICK_TOOLS]
    assert min(per) <= rows["feed_force.mae"]["ours"] <= max(per)
    w = rows["feed_force.interval_median_width"]["ours"] / rows["feed_force.mae"]["ours"]
    assert rows["feed_force.width_over_mae"]["ours"] == pytest.approx(w)
    checks = {c["name"]: c for c in out["checks"]}
    assert set(checks) == {
        f"feed_force.{n}"
        for n in (
            "mae_25pct_below_linear",
            "tools_lower_than_linear",
            "coverage_95",
            "width_over_mae",
            "life_at_half_300um",
        )
    } | {
        f"unseen.F_f.{n}"
        for n in (
            "mae_vs_linear",
            "mae_vs_gbr",
            "mae_vs_prior",
            "tools_beat_linear",
            "coverage",
            "tools_cov75",
            "width_over_mae",
            "life_at_half",
        )
    }
    c = checks["feed_force.mae_25pct_below_linear"]
    assert c["value"] == pytest.approx(
        rows["feed_force.mae"]["ours"] / rows["feed_force.mae"]["paper"]
    )
    assert c["holds"] == (c["value"] <= c["limit"])
    assert rc == (0 if all(c["holds"] for c in out["checks"]) else 1)
    _unseen_rows(rows, checks)


def _unseen_rows(rows: dict, checks: dict) -> None:
    """Issue 35's rows: the hybrid beside every baseline, per tool left out, the checks
    computed from the pooled rows."""
    from server.experiments.reproductions import turning_wear_unseen as unseen

    pre = "unseen.F_f.loto"
    for t in unseen.QUICK_TOOLS:
        r = rows[f"{pre}.tool.{t}.mae"]
        assert r["ours"] > 0 and r["paper"] > 0
    pooled = rows[f"{pre}.pooled.mae"]
    per = [rows[f"{pre}.tool.{t}.mae"]["ours"] for t in unseen.QUICK_TOOLS]
    assert min(per) <= pooled["ours"] <= max(per)
    c = checks["unseen.F_f.mae_vs_linear"]
    assert c["value"] == pytest.approx(pooled["ours"] / pooled["paper"])
    assert c["holds"] == (c["value"] <= 0.75)
    assert rows[f"{pre}.entry.record"]["ours"] > 0
    assert sum(r["ours"] for n, r in rows.items() if n.startswith(f"{pre}.chosen.")) == 2
    # the condition groups come from the data: tools 7 and 16 run at different speeds
    groups = {n: r for n, r in rows.items() if n.startswith(f"{pre}.group.")}
    assert len(groups) == 2 and all(r["ours"] > 0 for r in groups.values())
    assert {n.split(".")[4][:2] for n in groups} == {"S7", "S8"}, groups
    # what the selection believed of its choice beside what it made out of fold
    opt = rows[f"{pre}.optimism"]
    assert opt["unit"] == "um" and "of 30 configurations" in opt["condition"]
    assert abs(opt["ours"]) < 200
    # the life error taken apart: the estimate's, beside the measured state's
    lp = rows[f"{pre}.life_parts"]
    assert lp["ours"] >= 0 and lp["paper"] >= 0 and "true level + our rate" in lp["condition"]
    # revision 4: the prior rate's rule chosen in each of the two folds
    rl = rows[f"{pre}.rate_law"]
    assert 0 <= rl["ours"] <= 2 and rl["unit"] == "folds" and "[0.67, 5]" in rl["condition"]
    assert "revision 4" in rl["condition"] and "revision 5" not in rl["condition"]


def test_rate_law_row_says_what_ran() -> None:
    """Revision 5's folds are counted as the law per segment, with the fallback; revision
    4's as the Taylor-type law chosen, with its clipped slope."""
    from server.experiments.reproductions.turning_wear_unseen import rate_law_row

    seg = {"rate_laws": {"segment": 3}, "rate_b": [0.0, 1.0, 0.0], "splits": 3,
           "rate_b_out_of_range": 0, "rate_b_fallback": 1}  # fmt: skip
    r = rate_law_row("unseen.F_f.loto", seg)
    assert r.ours == 3 and "revision 5" in r.condition and "revision 4" not in r.condition
    assert "in 1 folds" in r.condition and "0.00-1.00" in r.condition
    rev4 = {"rate_laws": {"median": 2, "taylor": 1}, "rate_b": [0.67, 0.67, 2.0],
            "splits": 3, "rate_b_out_of_range": 2}  # fmt: skip
    r = rate_law_row("unseen.F_f.loto", rev4)
    assert r.ours == 1 and "revision 4" in r.condition and "[0.67, 5] (clipped) in 2" in r.condition
