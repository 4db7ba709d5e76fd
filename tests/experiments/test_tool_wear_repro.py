"""`cutwatch reproduce tool-wear`: rows, the issue's checks, CLI contract, plots."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from server.experiments.reproduction import Reproduction
from server.experiments.reproductions import seed004_tool_wear as tool_wear


@pytest.fixture(scope="module")
def rep() -> Reproduction:
    return tool_wear.run(quick=True, progress=False)


def _check(rep: Reproduction, name: str):
    for c in rep.checks:
        if c.name == name:
            return c
    raise KeyError(name)


def test_every_listed_row_is_produced(rep: Reproduction) -> None:
    names = [r.name for r in rep.rows]
    assert names == list(dict.fromkeys(names)), "duplicate rows"
    for n in tool_wear.ROWS:
        assert n in names
    for f in ("0.100", "0.125"):
        for p in ("a1", "a2", "a3", "b1", "b2", "b3"):
            assert f"params.f{f}.{p}" in names


def test_table1_within_one_percent(rep: Reproduction) -> None:
    # seed 004 Table 1 (source of the paper values in the reproduction module)
    c = _check(rep, "table1 parameters within 1 % of the paper's")
    assert c.holds, c
    assert rep.row("params.f0.100.b1").ours == pytest.approx(15.71587, rel=0.01)
    assert rep.row("params.f0.125.b1").ours == pytest.approx(12.8257, rel=0.01)


def test_section3_behaviour(rep: Reproduction) -> None:
    for c in rep.checks:
        if c.name.startswith("section 3"):
            assert c.holds, c


@pytest.mark.parametrize(
    "name",
    [
        "state_error.mean.x1 within twice Table 4's",
        "state_error.mean.x2 within twice Table 4's",
        "state_error.sd.x1 within twice Table 4's",
        "state_error.sd.x2 within twice Table 4's",
        "state_error.sd.x3 within twice Table 4's",
    ],
)
def test_state_error_within_twice_table4(rep: Reproduction, name: str) -> None:
    c = _check(rep, name)
    assert c.holds, c


@pytest.mark.xfail(
    strict=True,
    reason="measured |mean error of x03| = 1.52 N against the limit 1.50 N (twice Table 4's "
    "0.75 N); see docs/reproductions/seed004-tool-wear.md",
)
def test_state_error_mean_x3_within_twice_table4(rep: Reproduction) -> None:
    c = _check(rep, "state_error.mean.x3 within twice Table 4's")
    assert c.holds, c


def test_estimates_stay_inside_table2_constraints(rep: Reproduction) -> None:
    for t in ("t0_1min", "t1min", "t4min", "t12min", "t15min"):
        a1 = rep.row(f"table3.{t}.est.a1").ours
        b1 = rep.row(f"table3.{t}.est.b1").ours
        b2 = rep.row(f"table3.{t}.est.b2").ours
        assert -3.2 <= a1 <= -2.8
        assert -2.5 * b1 <= b2 <= -1.5 * b1


def test_sensorless_wear_and_life_rows_are_finite(rep: Reproduction) -> None:
    dyn = rep.row("wear.flank.rel_error.dynamometer").ours
    est = rep.row("wear.flank.rel_error.estimated_force").ours
    assert 0 < dyn < 0.1 and 0 < est < 0.1
    life = rep.row("life.true_min").ours
    assert 20 < life < 40
    warn = rep.row("life.warning_at_fraction").ours
    alarm = rep.row("life.alarm_at_fraction").ours
    assert 0 < warn < alarm


@pytest.mark.parametrize(
    "name",
    [
        "remaining life at 50 % of life within 3 sigma",
        "remaining life of mismatched tools within 3 sigma (25, 50, 75 % of life)",
    ],
)
def test_remaining_life_within_three_sigma(rep: Reproduction, name: str) -> None:
    c = _check(rep, name)
    assert c.holds, c


def test_remaining_life_error_reported_at_three_fractions(rep: Reproduction) -> None:
    for key in ("25pct", "75pct"):
        err = rep.row(f"life.prediction_error_min.{key}").ours
        sd = rep.row(f"life.prediction_sd_min.{key}").ours
        assert math.isfinite(err) and 0.0 < sd < math.inf
        assert abs(err) <= 3.0 * sd


def test_cli_json_contract_and_plots(tmp_path: Path) -> None:
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "server.cli.main",
            "reproduce",
            "tool-wear",
            "--quick",
            "--json",
            "--plot",
            str(tmp_path),
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    doc = json.loads(out.stdout)
    # exit status 1: one check fails — exactly the shortfall documented in
    # docs/reproductions/seed004-tool-wear.md, no other
    failing = {c["name"] for c in doc["checks"] if not c["holds"]}
    assert failing == {"state_error.mean.x3 within twice Table 4's"}
    assert out.returncode == 1
    assert doc["experiment"] == "tool-wear"
    names = {r["name"] for r in doc["rows"]}
    assert "state_error.sd.x3" in names and "life.prediction_error_min" in names
    pngs = sorted(p.name for p in tmp_path.glob("*.png"))
    assert pngs == ["tool_wear_life.png", "tool_wear_physical.png", "tool_wear_states.png"]
