"""The seed 000 / seed 001 reproductions at reduced length, through the real command.

Checks the issue asks for that our runs do not reach are strict xfails carrying the
measured numbers (docs/reproductions/seed000-adaptive-observer.md and
seed001-switching-rls.md): if one starts to hold, the suite says so.
"""

import json
import subprocess
import sys

import pytest

from server.experiments.reproduction import Reproduction
from server.experiments.reproductions import seed000_adaptive_observer as adaptive_observer
from server.experiments.reproductions import seed001_switching_rls as switching_rls


@pytest.fixture(scope="module")
def switching() -> Reproduction:
    return switching_rls.run(quick=True, progress=False)


@pytest.fixture(scope="module")
def adaptive() -> Reproduction:
    return adaptive_observer.run(quick=True, progress=False)


def _check(rep: Reproduction, text: str):
    return next(c for c in rep.checks if text in c.name)


def _rows(rep: Reproduction) -> dict[str, float]:
    return {r.name: r.ours for r in rep.rows}


def test_required_rows_are_present(switching, adaptive) -> None:
    for rep, mod in ((switching, switching_rls), (adaptive, adaptive_observer)):
        names = set(_rows(rep))
        for row in mod.ROWS:
            if "<" not in row:
                assert row in names
                assert "paper_recursion." + row in names or row == "J_L.true.weight"


def test_switching_rls_holds_f_cl_across_reversals(switching) -> None:
    c = _check(switching, "[ours] switching F_CL within 20 %")
    assert c.holds, c.value
    # and the papers' recursion confuses F_CL with the force's DC (seed 001 Fig. 8(b))
    g = _rows(switching)
    assert g["paper_recursion.F_CL.max_rel_error.ordinary.stationary"] > 0.3
    assert g["F_CL.max_rel_error.ordinary.stationary"] < 0.1


@pytest.mark.xfail(
    strict=True,
    reason="not reached: switching/ordinary RMS = 1.00 (target <= 0.9); both sit on the "
    "Q(s) floor once F_CL is right",
)
def test_switching_beats_ordinary_by_ten_percent(switching) -> None:
    assert _check(switching, "[ours] switching <= 0.9 x ordinary (stationary)").holds


def test_adaptive_equals_fixed_without_the_weight(adaptive) -> None:
    assert _check(adaptive, "[ours] adaptive within 5 % of fixed").holds
    assert _check(adaptive, "[paper recursion] adaptive within 5 % of fixed").holds


def test_adaptive_identifies_j_l_and_reaches_the_q_floor_with_the_weight(adaptive) -> None:
    g = _rows(adaptive)
    j_true = g["J_L.true.weight"]
    assert abs(g["J_L.identified.weight"] / j_true - 1) < 0.05
    assert abs(g["J_L.identified.nominal"] / 2.8e-4 - 1) < 0.08
    # the adaptive error is within 1 % of the floor Q(s) F_cut; the fixed one is not
    assert g["rms_error.adaptive.weight"] < 1.01 * g["rms_error.ideal.weight"]
    assert g["rms_error.fixed.weight"] > 1.1 * g["rms_error.ideal.weight"]


@pytest.mark.xfail(
    strict=True,
    reason="not reached: adaptive/fixed = 0.855 with the weight (target <= 0.8); the floor "
    "Q(s) F_cut / fixed is 0.854 with this Q(s)",
)
def test_adaptive_beats_fixed_by_twenty_percent_with_the_weight(adaptive) -> None:
    assert _check(adaptive, "[ours] adaptive <= 0.8 x fixed").holds


@pytest.mark.xfail(
    strict=True,
    reason="not reached: J_L settles in 6.0 s (target 5 s): it needs the second velocity "
    "reversal after the change, and reversals come every 4 s",
)
def test_j_l_settles_within_five_seconds(adaptive) -> None:
    assert _check(adaptive, "[ours] J_L within 10 % within 5 s").holds


def test_reproduce_cli_json_contract() -> None:
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "server.cli.main",
            "reproduce",
            "switching-rls",
            "--quick",
            "--json",
        ],
        capture_output=True,
        text=True,
    )
    doc = json.loads(out.stdout)
    assert doc["experiment"] == "switching-rls"
    assert {"name", "ours", "paper", "unit"} <= set(doc["rows"][0])
    assert all({"name", "holds", "value", "limit"} <= set(c) for c in doc["checks"])
    # a check that does not hold makes the command exit 1
    assert out.returncode == (0 if all(c["holds"] for c in doc["checks"]) else 1)


def test_reproduce_cli_rejects_unknown_names() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "server.cli.main", "reproduce", "nope"],
        capture_output=True,
        text=True,
    )
    assert out.returncode == 2
    assert "unknown experiment 'nope'" in out.stderr
    assert "adaptive-observer" in out.stderr
