"""`cutwatch reproduce centre-wear --quick --json`: its rows, and the metrics it pools."""

from __future__ import annotations

import json

import numpy as np
import pytest

from server.cli.main import main
from server.experiments.reproductions import centre_wear


def test_metrics_pool_error_coverage_and_width() -> None:
    # (tool, instance, calibrated, true, estimate, low, high, t) [m]
    r = np.array([[1, 1, 0, 1e-4, 1.2e-4, 0.5e-4, 2e-4, 5.0],
                  [1, 1, 0, 2e-4, 1.5e-4, 1.0e-4, 1.8e-4, 10.0]])  # fmt: skip
    m = centre_wear.metrics(r)
    assert m["mae"] == pytest.approx(35e-3)  # mm
    assert m["coverage"] == 0.5 and m["n"] == 2
    assert m["width"] == pytest.approx(np.median([1.5e-4, 0.8e-4]) * 1e3)
    assert np.isnan(centre_wear.metrics(r[:0])["mae"])


def test_quick_json_rows(capsys: pytest.CaptureFixture) -> None:
    rc = main(["reproduce", "centre-wear", "--quick", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert out["experiment"] == "centre-wear" and rc == 0  # no checks on the quick run
    rows = {r["name"]: r for r in out["rows"]}
    # five minutes of machine time: every tool taught and read, no tool worn out yet
    for t in (1, 2, 3):
        assert rows[f"uncalibrated.tool.{t}.mae"]["ours"] > 0
    assert 0.0 <= rows["uncalibrated.coverage"]["ours"] <= 1.0
    assert 0 < rows["uncalibrated.mae"]["ours"] < 0.3  # mm: under the limit itself
    assert rows["tool_changes.made"]["ours"] == rows["tool_changes.detected"]["ours"] == 0
