"""`cutwatch reproduce trace-rates --quick`: the two-inertia axis at 2.5 kHz, 1 kHz and
500 Hz, point-sampled and cycle-averaged (issue 30 item 5)."""

from __future__ import annotations

import json

import pytest

from server.cli.main import main


def test_quick_json(capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["reproduce", "trace-rates", "--quick", "--json"])
    out = json.loads(capsys.readouterr().out)
    failed = [c["name"] for c in out["checks"] if not c["holds"]]
    assert rc == 0 and failed == []
    rows = {r["name"]: r for r in out["rows"]}
    for rate in (2500, 1000, 500):
        for model in ("point", "average"):
            key = f"{rate}Hz.{model}"
            assert rows[f"{key}.J_L_within_10_of_excited"]["ours"] >= 80.0
            assert rows[f"{key}.J_L_excited"]["ours"] > 50.0
            assert rows[f"{key}.force_rms_ratio_to_2500"]["ours"] <= 1.5
    assert "Nyquist" in rows["500Hz.point.force_rms_ratio_to_2500"]["condition"]
