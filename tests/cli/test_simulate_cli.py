"""`cutwatch simulate` writes a measured log that reads back through the log loader."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from server.cli.main import main
from server.records.measured_log import load_log


def test_simulate_writes_a_log_with_an_undeclared_effect(tmp_path: Path) -> None:
    out = tmp_path / "run.csv"
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "server.cli.main",
            "simulate",
            "--out",
            str(out),
            "--seconds",
            "1.5",
            "--effect",
            "coulomb_asymmetry",
        ],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stderr
    log = load_log(out)
    assert log.n == round(1.5 / 4e-4)
    assert log.kind == "two_inertia"
    assert abs(log.sample_time - 4e-4) < 1e-12
    assert {"t", "tau_m", "q_m", "q_l", "f_ext"} <= set(log.columns)
    # the sidecar tells the nominal parameters, not the effect
    side = json.loads(out.with_suffix(".json").read_text())
    assert "coulomb_asymmetry" not in json.dumps(side)
    assert side["nominal"]["J_L"] == 2.8e-4
    truth = json.loads(out.with_suffix(".truth.json").read_text())
    assert truth["effects"] == ["coulomb_asymmetry"]
    # the motor angle moves forward on the first plateau
    assert np.all(np.isfinite(log["q_m"])) and log["q_m"][-1] > 10.0


def test_simulate_refuses_bad_input(tmp_path: Path) -> None:
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "server.cli.main",
            "simulate",
            "--out",
            str(tmp_path / "x.csv"),
            "--seconds",
            "-1",
        ],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 2
    assert "--seconds: expected a value in (0, 3600], got -1" in r.stderr
    assert not (tmp_path / "x.csv").exists()
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "server.cli.main",
            "simulate",
            "--out",
            str(tmp_path / "x.csv"),
            "--effect",
            "gravity",
        ],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 2
    assert "invalid choice: 'gravity'" in r.stderr


def test_seed_varies_motion_noise_and_effect(tmp_path: Path) -> None:
    """--seed draws a Monte Carlo case; without it the log is the fixed default one."""
    from server.records.measured_log import load_log

    paths = {}
    for name, extra in (("a", []), ("b", []), ("s1", ["--seed", "1"]), ("s2", ["--seed", "2"])):
        paths[name] = tmp_path / f"{name}.csv"
        argv = ["simulate", "--out", str(paths[name]), "--seconds", "1", *extra]
        assert main([*argv, "--effect", "position_periodic"]) == 0
    assert paths["a"].read_bytes() == paths["b"].read_bytes()
    s1, s2 = (json.loads(paths[k].with_suffix(".json").read_text()) for k in ("s1", "s2"))
    assert s1["trajectory"] != s2["trajectory"]
    t1, t2 = (json.loads(paths[k].with_suffix(".truth.json").read_text()) for k in ("s1", "s2"))
    p1, p2 = t1["effect_parameters"], t2["effect_parameters"]
    assert p1["position_phase"] != p2["position_phase"]
    assert 0.7 * 0.2 <= p1["position_periodic"] <= 1.3 * 0.2
    assert 0.01 <= t1["current_noise"] <= 0.05
    q1, q2 = load_log(paths["s1"])["q_l"], load_log(paths["s2"])["q_l"]
    assert not np.allclose(q1, q2)


def test_bad_vary(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["simulate", "--out", str(tmp_path / "x.csv"), "--seed", "1", "--vary", "speed"]
    assert main(argv) == 2
    assert "--vary: expected names among motion, noise, effect, got 'speed'" in (
        capsys.readouterr().err
    )
