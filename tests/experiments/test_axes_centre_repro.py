"""`cutwatch reproduce axes-centre --quick`: the axes' process force on the machining
centre's 500 Hz trace, the rigid model's and the two-inertia observer's (issue 31 item 2)."""

from __future__ import annotations

import json

import pytest

from server.cli.main import main


def test_quick_json(capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["reproduce", "axes-centre", "--quick", "--json"])
    out = json.loads(capsys.readouterr().out)
    failed = [c["name"] for c in out["checks"] if not c["holds"]]
    assert rc == 0 and failed == []
    rows = {r["name"]: r for r in out["rows"]}
    for a in "XY":
        assert rows[f"{a}.F_err_share"]["ours"] < 0.5
    assert rows["X.F_2i_over_F"]["ours"] < 0.85
    assert rows["X.mode_hz"]["ours"] == pytest.approx(130.0, rel=0.03)
    assert rows["X.M_L"]["ours"] == pytest.approx(rows["X.M_L"]["paper"], rel=0.05)
