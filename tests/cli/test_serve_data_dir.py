"""``cutwatch serve --data-dir``: the service's data areas, and the reports area within."""

from __future__ import annotations

from pathlib import Path

import pytest

from server.cli.commands.serve import build_settings
from server.cli.main import build_parser


def test_data_dir_option_and_reports_area(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("CUTWATCH_DATA_DIR", raising=False)
    monkeypatch.delenv("CUTWATCH_REPORTS_DIR", raising=False)
    s = build_settings(build_parser().parse_args(["serve"]))
    assert s.data_dir == Path("data") and s.reports_area == Path("data/reports")
    s = build_settings(build_parser().parse_args(["serve", "--data-dir", "/srv/cw"]))
    assert s.data_dir == Path("/srv/cw") and s.reports_area == Path("/srv/cw/reports")
    monkeypatch.setenv("CUTWATCH_REPORTS_DIR", "/srv/reports")  # the old setting still wins
    s = build_settings(build_parser().parse_args(["serve", "--data-dir", "/srv/cw"]))
    assert s.reports_area == Path("/srv/reports")
