"""`cutwatch reproduce rigid-live --quick --json`: the EMPS record identified live from no
prior (issue 30 item 3, 4), and the intervals' coverage over seeds."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from server.cli.main import main
from server.experiments.reproductions import rigid_live

pytestmark = pytest.mark.skipif(
    not any(
        (p / "shared" / "data" / "emps" / "DATA_EMPS.mat").exists()
        for p in Path(__file__).resolve().parents
    ),
    reason="EMPS data not present",
)


def test_emps_live_against_idim_ls_and_the_report(capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["reproduce", "rigid-live", "--quick", "--json"])
    out = json.loads(capsys.readouterr().out)
    checks = {c["name"]: c for c in out["checks"]}
    failed = [n for n, c in checks.items() if not c["holds"]]
    assert rc == 0 and failed == [], failed
    rows = {r["name"]: r for r in out["rows"]}
    for k in ("M", "Fv", "Fc"):
        r = rows[f"emps.live.{k}"]
        assert r["paper"] == rigid_live.IDIM[k]
        tol = rigid_live.TOLERANCE[k]
        assert abs(r["ours"] / r["paper"] - 1) <= tol  # the 5 % / 10 %
        assert rows[f"emps.live.{k}_half_pct"]["ours"] <= 10.0
        # the robust interval is wider than plain least squares' on this record
        assert (
            rows[f"emps.live.{k}_half_pct"]["ours"] > rows[f"emps.live.{k}_half_plain_pct"]["ours"]
        )
    assert 0 < rows["emps.live.time_to_target"]["ours"] < 24.84
    assert rows["emps.live.reversals_to_target"]["ours"] <= 7  # the record has 7
    without = rows["emps.live.relerr_last40_without"]["ours"]
    assert rows["emps.live.relerr_last40_with_report"]["ours"] < without < 6.0
    # a real CNC's 10 Hz export: Fc per axis from the CNC's velocity and acceleration,
    # beside the batch fit on every moving row; Z's current column is 0 throughout
    for ax in ("X", "Y"):
        fc = rows[f"cnc.experiment_01.{ax}.Fc"]
        assert abs(fc["ours"] / fc["paper"] - 1) < 0.1 and fc["condition"].startswith("excited")
        assert rows[f"cnc.experiment_01.{ax}.M"]["condition"].startswith("not excited")
    assert "cnc.experiment_01.Z.effort_silent" in rows
    # coverage: plain least squares narrower than Newey-West on every parameter
    for k in ("M", "Fv", "Fc", "offset"):
        assert rows[f"coverage.ripple_noise.{k}.width_ratio"]["ours"] > 1.2
        hac = rows[f"coverage.ripple_noise.{k}.newey_west"]["ours"]
        assert hac >= rows[f"coverage.ripple_noise.{k}.plain"]["ours"]


def test_time_to_target_is_from_then_on() -> None:
    ok = {"theta": [95.1, 203.5, 20.4], "half": [1.0, 5.0, 1.0], "reversals": 3}
    bad = {**ok, "theta": [80.0, 203.5, 20.4]}
    hist = [{**bad, "t": 1.0}, {**ok, "t": 2.0}, {**bad, "t": 3.0}, {**ok, "t": 4.0},
            {**ok, "t": 5.0, "reversals": 4}]  # fmt: skip
    assert rigid_live.time_to_target(hist) == (4.0, 3)
    assert rigid_live.time_to_target(hist[:3])[0] != rigid_live.time_to_target(hist[:3])[0]
