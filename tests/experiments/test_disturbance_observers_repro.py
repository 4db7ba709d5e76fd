"""`cutwatch reproduce disturbance-observers`: seed 002 Tables 1-2 through the real CLI."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from estimators import imbdo as im
from machine import xy_axis as xa
from server.cli.main import main
from server.experiments.reproductions import seed002_disturbance_observers as do

REQUIRED = [
    *(f"rmse.{c}" for c in do.CONFIGS),
    *(f"mte.{c}" for c in do.CONFIGS),
    *(f"peak.{f}hz.{c}" for c in do.CONFIGS for f in (26, 52, 78)),
]
STAGE = [f"stage.err_{f}hz.{w}" for f in (100, 200) for w in ("before", "after")]


@pytest.fixture(scope="module")
def report(tmp_path_factory: pytest.TempPathFactory) -> dict[str, object]:
    plots = tmp_path_factory.mktemp("plots")
    out = tmp_path_factory.mktemp("out") / "rep.json"
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = main(["reproduce", "disturbance-observers", "--quick", "--json", "--plot", str(plots)])
    out.write_text(buf.getvalue())
    rep = json.loads(buf.getvalue())
    rep["_rc"] = rc
    return rep


def test_rows_named_in_the_issue_are_present(report: dict[str, object]) -> None:
    rows = {r["name"]: r for r in report["rows"]}  # type: ignore[attr-defined]
    for name in REQUIRED:
        assert name in rows, name
        assert rows[name]["ours"] is not None
        assert rows[name]["paper"] is not None  # Table 1 / Table 2 value beside ours
    for name in STAGE:
        assert rows[name]["ours"] is not None, name
    assert set(do.ROWS) == set(REQUIRED + STAGE)


def test_stage_rows_improve_and_the_observer_reconverges(report: dict[str, object]) -> None:
    rows = {r["name"]: r["ours"] for r in report["rows"]}  # type: ignore[attr-defined]
    for f in (100, 200):
        assert rows[f"stage.err_{f}hz.after"] < rows[f"stage.err_{f}hz.before"]
    for f in (80, 160):  # after the spindle-speed change, with the retuned frequencies
        assert rows[f"stage.err_{f}hz.after"] < rows[f"stage.err_{f}hz.before"]
    assert 0.0 < rows["stage.reconverge_5pct"] < 1.0


def test_checks_hold_on_the_quick_run(report: dict[str, object]) -> None:
    checks = report["checks"]
    assert [c["name"] for c in checks if not c["holds"]] == []  # type: ignore[attr-defined]
    assert report["_rc"] == 0
    names = {c["name"] for c in checks}  # type: ignore[attr-defined]
    assert "peak.26hz reduction combined vs pi >= 60 %" in names
    assert "rmse.combined < rmse.dfo" in names


def test_paper_reference_numbers_are_the_tables(report: dict[str, object]) -> None:
    rows = {r["name"]: r for r in report["rows"]}  # type: ignore[attr-defined]
    # seed 002 Table 1 and Table 2
    assert rows["rmse.combined"]["paper"] == 0.0978
    assert rows["mte.pi"]["paper"] == 0.1477
    assert rows["peak.26hz.pi"]["paper"] == 3.158
    assert rows["peak.78hz.combined"]["paper"] == 0.2412
    # the force is calibrated on the P/PI row: ours lands within 5 % of it
    assert rows["peak.26hz.pi"]["ours"] == pytest.approx(3.158, rel=0.05)


def test_figures_are_written(report: dict[str, object]) -> None:
    figs = report["figures"]
    assert len(figs) == 3  # type: ignore[arg-type]
    for f in figs:  # type: ignore[attr-defined]
        p = Path(f)
        assert p.suffix == ".png" and p.stat().st_size > 10_000


def test_list_names_the_rows(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["reproduce", "--list"]) == 0
    out = capsys.readouterr().out
    assert "disturbance-observers" in out
    assert "peak.78hz.combined" in out


def test_bench_group_reports_realtime_factors(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "disturbance-observers", "--quick", "--repeats", "1", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)["disturbance-observers"]
    for c in do.CONFIGS:
        assert res[f"xy_{c}_realtime_factor"] > 0
    assert res["dfo_3harmonics_2500hz_realtime_factor"] > 0


def test_delay_free_imbdo_destabilises_the_papers_loop_and_the_delayed_one_does_not() -> None:
    # the finding behind the IMBDO choice, simulated by the reproduction's loop
    axis = xa.XYAxisParams()
    free = im.ImbdoParams(
        axis.a, axis.b, axis.c, axis.sample_time, model_delay=0.0, delay_uncertainty=axis.delay
    )
    assert free.stability.holds  # eq. (4) alone does not see it: the cascade does
    bad = do.simulate("imbdo", 0.3, axis=axis, imbdo=free)
    good = do.simulate("imbdo", 0.3, axis=axis)
    assert np.max(np.abs(bad.ref - bad.z)) > 1e3  # mm: diverging
    assert np.max(np.abs(good.ref - good.z)) < 0.2
    gain, f180 = do.delay_free_imbdo_loop(axis, xa.CascadeParams())
    assert gain > 1.0 and 100.0 < f180 < 125.0
