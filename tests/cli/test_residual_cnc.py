"""A real CNC's 10 Hz export through `cutwatch residual` as it comes (issue 18 item 2):
the command as written, the options, the refusals, and `cutwatch reproduce cnc-mill`."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from server.cli.main import main


def _data() -> Path:
    from server.errors import CutwatchError
    from server.experiments.reproductions.cnc_mill import data_dir

    try:
        return data_dir()
    except CutwatchError:
        return Path("cnc-mill-not-found")


CNC = _data()
needs_data = pytest.mark.skipif(not CNC.exists(), reason="cnc-mill data not present")
META = '{"sample_time": 0.1, "units": {"effort": "A", "position": "m"}}'
IDLE = (
    "S1_ActualVelocity<1 & X1_ActualPosition==198 & Y1_ActualPosition==158 & Z1_ActualPosition==119"
)


def _run(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main(["residual", *args, "--quiet"])
    cap = capsys.readouterr()
    return code, cap.out, cap.err


@needs_data
def test_the_command_as_written_runs_on_the_export(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "x1"
    code, text, err = _run(
        [str(CNC / "experiment_01.csv"), "--meta", META, "--map", "q_m=X1_ActualPosition*0.001",
         "--map", "tau_m=X1_CurrentFeedback", "--out", str(out)],
        capsys,
    )  # fmt: skip
    assert code == 0, err
    rep = json.loads((out / "report.json").read_text())
    assert rep["units"]["effort"] == "A" and rep["n_samples"] == 1055
    assert rep["sample_time"] == pytest.approx(0.1)
    # at 10 Hz: friction and load only; inertia and cogging not offered, with the reason
    offered = {c["name"] for c in rep["candidates"]}
    assert offered <= {"offset", "viscous", "coulomb_asymmetry", "stribeck",
                       "position_friction", "drift"}  # fmt: skip
    for name in ("inertia", "position_periodic", "position_harmonics", "harmonic"):
        assert "Hz" in rep["not_offered"][name] or "ms" in rep["not_offered"][name]
    assert any("10 Hz" in n for n in rep["notes"]) and "10 Hz" in text
    assert rep["relerr_after"] <= rep["relerr_before"]


@needs_data
def test_velocity_columns_rows_and_load(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "y6"
    code, text, err = _run(
        [str(CNC / "experiment_06.csv"), "--meta", META,
         "--map", "q_m=Y1_ActualPosition*0.001", "--map", "tau_m=Y1_CurrentFeedback",
         "--map", "qd_m=Y1_ActualVelocity*0.001", "--map", "qdd_m=Y1_ActualAcceleration*0.001",
         "--drop", IDLE, "--drop-repeats", "X1_*,Y1_*,Z1_*,S1_*",
         "--load-rows", "S1_ActualVelocity>1 & Z1_ActualPosition<30", "--out", str(out)],
        capsys,
    )  # fmt: skip
    assert code == 0, err
    rep = json.loads((out / "report.json").read_text())
    assert rep["rows"]["read"] == 1296 and rep["rows"]["used"] == 1137
    assert [d["left_out"] for d in rep["rows"]["left_out"]] == [159, 0]
    assert rep["rows"]["pieces"] > 1
    assert "load" in {c["name"] for c in rep["candidates"]}
    assert any("controller's velocity" in n for n in rep["notes"])
    assert "rows read 1296, used 1137; left out: 159 by --drop" in text
    page = (out / "report.html").read_text()
    assert page.index('class="verdict"') < page.index("Raw coefficients")


@needs_data
def test_nominal_fitted_where_the_label_says_the_tool_is_in_the_air(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "air"
    code, _, err = _run(
        [str(CNC / "experiment_01.csv"), "--meta", META,
         "--map", "q_m=X1_ActualPosition*0.001", "--map", "tau_m=X1_CurrentFeedback",
         "--map", "qd_m=X1_ActualVelocity*0.001",
         "--nominal-rows", "Machining_Process~^(Prep|Repositioning|end)", "--out", str(out)],
        capsys,
    )  # fmt: skip
    assert code == 0, err
    rep = json.loads((out / "report.json").read_text())
    assert any("--nominal-rows" in n for n in rep["notes"])


@needs_data
@pytest.mark.parametrize(
    ("extra", "match"),
    [
        (
            ["--keep", "Machining_Process<3"],
            r"experiment_01.csv: --keep 'Machining_Process<3': column 'Machining_Process', "
            r"row 1: expected numbers for '<', found text 'Starting'",
        ),
        (
            ["--load-rows", "Spindle>1"],
            r"--load-rows 'Spindle>1': column 'Spindle' does not "
            r"exist; found ",
        ),
        (
            ["--map", "f_ext=Machining_Process"],
            r"row 1 \(line 2\), column 'Machining_Process': expected a number, found 'Starting'",
        ),
        (
            ["--keep", "Machining_Process==Prep"],
            r"too few samples for the held-out split \(30 rows\)",
        ),
    ],
)
def test_refusals_name_file_column_row_expected_found(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str], match: str
) -> None:
    import re

    code, _, err = _run(
        [str(CNC / "experiment_01.csv"), "--meta", META, "--map", "q_m=X1_ActualPosition*0.001",
         "--map", "tau_m=X1_CurrentFeedback", *extra, "--out", str(tmp_path / "o")],
        capsys,
    )  # fmt: skip
    assert code == 2
    assert re.search(match, err), err
    assert "Traceback" not in err and not (tmp_path / "o").exists()


@needs_data
def test_cr_only_export_gives_the_same_report(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    raw = (CNC / "experiment_01.csv").read_bytes().replace(b"\r\n", b"\n")
    reps = []
    for name, data in (("lf.csv", raw), ("cr.csv", raw.replace(b"\n", b"\r")),
                       ("crlf.csv", raw.replace(b"\n", b"\r\n"))):  # fmt: skip
        (tmp_path / name).write_bytes(data)
        out = tmp_path / f"out_{name}"
        code, _, err = _run(
            [str(tmp_path / name), "--meta", META, "--map", "q_m=X1_ActualPosition*0.001",
             "--map", "tau_m=X1_CurrentFeedback", "--map", "qd_m=X1_ActualVelocity*0.001",
             "--out", str(out)],
            capsys,
        )  # fmt: skip
        assert code == 0, err
        reps.append(json.loads((out / "report.json").read_text()))
    assert reps[0]["relerr_after"] == reps[1]["relerr_after"] == reps[2]["relerr_after"]
    assert reps[0]["parameters_after"] == reps[1]["parameters_after"]


@needs_data
def test_reproduce_cnc_mill_quick_json(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["reproduce", "cnc-mill", "--quick", "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    rows = {r["name"]: r for r in rep["rows"]}
    for axis in ("X", "Y"):
        row = rows[f"exp01.{axis}.heldout_relerr (paper: nominal LS)"]
        assert row["ours"] <= row["paper"]
    checks = {c["name"]: c for c in rep["checks"]}
    r2 = next(c for n, c in checks.items() if n.startswith("exp01.X: the nominal fit"))
    assert r2["holds"] and abs(r2["value"] - 0.64) <= 0.03


def test_help_names_the_row_options(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["residual", "--help"])
    text = capsys.readouterr().out
    for opt in ("--keep COND", "--drop COND", "--drop-repeats COLS", "--nominal-rows COND",
                "--load-rows COND", "qd_m", "sample_time"):  # fmt: skip
        assert opt in text, opt
