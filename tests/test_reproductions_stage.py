"""The seed 000 / seed 001 reproductions at reduced length, through the real command."""

import json
import subprocess
import sys

import pytest

from server.reproductions import adaptive_observer, switching_rls


@pytest.fixture(scope="module")
def switching():
    return switching_rls.run(quick=True, progress=False)


@pytest.fixture(scope="module")
def adaptive():
    return adaptive_observer.run(quick=True, progress=False)


def test_switching_rls_rows_and_checks_hold(switching) -> None:
    names = {r.name for r in switching.rows}
    for row in switching_rls.ROWS[:-1]:
        assert row in names
    for c in switching.checks:
        assert c.holds, (c.name, c.value, c.limit)


def test_adaptive_observer_rows_present(adaptive) -> None:
    names = {r.name for r in adaptive.rows}
    for row in adaptive_observer.ROWS[:-1]:
        assert row in names
    # the ideal (Q(s) of the true force) is the floor no observer beats by much
    g = {r.name: r.ours for r in adaptive.rows}
    assert g["rms_error.adaptive.weight"] > 0.95 * g["rms_error.ideal.weight"]


def test_adaptive_equals_fixed_without_the_weight(adaptive) -> None:
    c = next(c for c in adaptive.checks if "without the weight" in c.name)
    assert c.holds, c.value


@pytest.mark.xfail(
    strict=True,
    reason="not reached: adaptive/fixed = 0.99 with the weight "
    "(target <= 0.8); J_L does not settle within 10 % (see README)",
)
def test_adaptive_beats_fixed_with_the_weight(adaptive) -> None:
    for c in adaptive.checks:
        assert c.holds, (c.name, c.value)


def test_reproduce_cli_json_contract() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "server.cli", "reproduce", "switching-rls", "--quick", "--json"],
        capture_output=True,
        text=True,
        check=True,
    )
    doc = json.loads(out.stdout)
    assert doc["experiment"] == "switching-rls"
    assert {"name", "ours", "paper", "unit"} <= set(doc["rows"][0])
    assert all({"name", "holds", "value", "limit"} <= set(c) for c in doc["checks"])


def test_reproduce_cli_rejects_unknown_names() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "server.cli", "reproduce", "nope"], capture_output=True, text=True
    )
    assert out.returncode == 2
    assert "unknown experiment 'nope'" in out.stderr
    assert "adaptive-observer" in out.stderr
