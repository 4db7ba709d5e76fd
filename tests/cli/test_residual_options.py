"""Every option combination of `cutwatch residual` gives a result or a clear message.

Issue 12 item 7: ``--holdout`` 0.1 ... 0.5, short logs, one direction of motion only,
no rests — for both kinds. Each example runs the real command on a real log file; the
outcome must be exit code 0 with a report, or exit code 2 with a one-line message that
names what is wrong (never a traceback).
"""

from __future__ import annotations

import json
import math
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from server.cli.main import main
from server.experiments.residual_logs import (
    RIGID_SIDECAR,
    rigid_log,
    simulate_stage,
    stage_case,
)
from server.records.measured_log import write_log


def _outcome(log: Path, holdout: float, capsys: pytest.CaptureFixture[str]) -> dict | None:
    out = log.parent / "out"
    code = main(["residual", str(log), "--holdout", f"{holdout:.3f}", "--out", str(out), "--quiet"])
    err = capsys.readouterr().err
    assert "Traceback" not in err
    if code == 0:
        rep = json.loads((out / "report.json").read_text())
        _check_report(rep)
        return rep
    assert code == 2
    # a message that names the log or the option and what was expected
    assert "expected" in err or "needs" in err or "too few" in err, err
    assert out.exists() is False
    return None


def _check_report(rep: dict) -> None:
    """What a report must say whatever the options: a consistent selection and its errors.

    The selected effects are distinct, each is the candidate marked selected and it passed
    the test (Holm and the minimum effect size) at its round, and the report's effects list
    them in the same order; no effect selected leaves the model and so the held-out error
    unchanged; the errors are finite and the held-out span is inside the record.
    """
    selected = rep["selected"]
    assert len(set(selected)) == len(selected), selected
    marked = [c["name"] for c in rep["candidates"] if c["selected"]]
    assert sorted(marked) == sorted(selected), (marked, selected)
    assert all(c["passed"] for c in rep["candidates"] if c["selected"]), rep["candidates"]
    assert [e["name"] for e in rep["effects"]] == selected
    assert math.isfinite(rep["rms_before"]) and rep["rms_before"] > 0.0
    assert math.isfinite(rep["rms_after"]) and rep["rms_after"] > 0.0
    if not selected:
        assert rep["rms_after"] == pytest.approx(rep["rms_before"], rel=1e-9, abs=0.0)
    hold = rep["holdout"]
    duration = (rep["n_samples"] - 1) * rep["sample_time"]
    assert 0.0 <= hold["start"] < hold["stop"] <= duration * (1 + 1e-9), (hold, duration)


def _rigid_one_direction(n: int, seed: int, rests: bool) -> dict[str, np.ndarray]:
    """A rigid axis moving one way only (q increasing), optionally with rests."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 1e-3
    v = 0.02 + 0.01 * np.sin(2 * np.pi * 0.4 * t)  # > 0: one direction
    if rests:
        v = np.where(np.sin(2 * np.pi * 0.25 * t) > 0.6, 0.0, v)
    q = np.cumsum(v) * 1e-3
    qdd = np.gradient(v, 1e-3)
    f = 20 * qdd + 100 * v + 8 * np.sign(v) - 1.0 + rng.normal(0.0, 1.0, n)
    return {"t": t, "tau_m": f, "q_m": q}


@settings(
    max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    holdout=st.floats(0.1, 0.5),
    seconds=st.sampled_from([0.8, 1.5, 3.0, 8.0]),
    shape=st.sampled_from(["both_ways", "one_way", "one_way_rests"]),
    effect=st.sampled_from(["none", "stribeck", "coulomb_asymmetry", "drift"]),
    seed=st.integers(0, 10_000),
)
def test_rigid_any_options(
    holdout: float,
    seconds: float,
    shape: str,
    effect: str,
    seed: int,
    capsys: pytest.CaptureFixture[str],
) -> None:
    n = int(seconds * 1000)
    if shape == "both_ways":
        cols = rigid_log(effect, n, seed)
    else:
        cols = _rigid_one_direction(n, seed, rests=shape == "one_way_rests")
    with tempfile.TemporaryDirectory() as tmp:
        log = Path(tmp) / "r.csv"
        write_log(log, cols, RIGID_SIDECAR)
        _outcome(log, holdout, capsys)


@settings(
    max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    holdout=st.floats(0.1, 0.5),
    seconds=st.sampled_from([0.5, 2.0, 5.0]),
    one_way=st.booleans(),
    rests=st.booleans(),
    effect=st.sampled_from(["none", "offset", "stribeck", "backlash"]),
    seed=st.integers(0, 10_000),
)
def test_two_inertia_any_options(
    holdout: float,
    seconds: float,
    one_way: bool,
    rests: bool,
    effect: str,
    seed: int,
    capsys: pytest.CaptureFixture[str],
) -> None:
    case = stage_case(
        [] if effect == "none" else [effect],
        seed,
        # one direction: the first reversal after the end of the record
        half_period=1000.0 if one_way else None,
        dwell=None if rests else 0.0,
    )
    cols, side, _ = simulate_stage(case, seconds, seed=seed)
    with tempfile.TemporaryDirectory() as tmp:
        log = Path(tmp) / "s.csv"
        write_log(log, cols, side)
        _outcome(log, holdout, capsys)


def test_one_direction_two_inertia_names_what_it_can(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A 6 s record moving one way only, with an offset: a result (not a crash)."""
    case = stage_case(["offset"], None, half_period=1000.0, dwell=0.0)
    cols, side, _ = simulate_stage(case, 6.0)
    log = tmp_path / "one.csv"
    write_log(log, cols, side)
    rep = _outcome(log, 0.3, capsys)
    assert rep is not None
    assert rep["rms_after"] <= rep["rms_before"]
