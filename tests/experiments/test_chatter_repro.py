"""`cutwatch reproduce chatter --quick`: the benchmark, the simulator grid, the drives."""

from __future__ import annotations

import contextlib
import io
import json
import math
from pathlib import Path

import pytest

from server.cli.main import main


@pytest.fixture(scope="module")
def report(tmp_path_factory: pytest.TempPathFactory) -> dict[str, object]:
    plots = tmp_path_factory.mktemp("plots")
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = main(["reproduce", "chatter", "--quick", "--json", "--plot", str(plots)])
    rep: dict[str, object] = json.loads(buf.getvalue())
    rep["_rc"] = rc
    return rep


def _rows(rep: dict[str, object]) -> dict[str, dict[str, object]]:
    return {r["name"]: r for r in rep["rows"]}  # type: ignore[attr-defined,index]


def _checks(rep: dict[str, object]) -> dict[str, dict[str, object]]:
    return {c["name"]: c for c in rep["checks"]}  # type: ignore[attr-defined,index]


def test_every_check_carries_lobe_and_the_figures_exist(report: dict[str, object]) -> None:
    checks = _checks(report)
    assert checks and all("lobe" in name for name in checks)
    figs = report["figures"]
    assert isinstance(figs, list) and len(figs) == 2
    assert all(Path(f).is_file() and Path(f).stat().st_size > 10_000 for f in figs)
    # a check that does not hold makes the command say so (exit 1), never crash
    assert report["_rc"] == (0 if all(c["holds"] for c in checks.values()) else 1)


def test_the_issue_rows_are_there(report: dict[str, object]) -> None:
    rows = _rows(report)
    for name in (
        "ad1.7500rpm.sd_depth_mm",
        "ad1.7500rpm.zoa_gap",
        "ad0.05.20000rpm.sd_depth_mm",
        "ad1.zoa_gap.max_abs",
        "ad1.zoa_gap.at_minimum",
        "ad0.05.flip_fraction",
        "grid.all.agreement_far",
        "grid.all.agreement_near",
        "drives.922hz.average_2ms_db",
        "drives.922hz.alias_500_hz",
        "drives.922hz.alias_1k_hz",
        "drives.flip_20000rpm.spindle_harmonic",
        "demo.onset_after_step_s",
        "chain.trace500.measured_ma",
    ):
        assert name in rows, name
    assert rows["ad1.7500rpm.sd_depth_mm"]["paper"] is None  # no published table found


def test_the_reference_converged_and_matches_the_zoa_when_averaged(
    report: dict[str, object],
) -> None:
    checks = _checks(report)
    assert checks["lobe.sd_converged_below_0.5pct"]["holds"]
    assert checks["lobe.sd_averaged_equals_zoa"]["holds"]


def test_the_zoa_misses_the_flip_lobes_at_low_immersion(report: dict[str, object]) -> None:
    rows = _rows(report)
    flips = [r for n, r in rows.items() if n.startswith("ad0.05.flip_lobe") and "zoa_over" in n]
    assert flips and max(float(r["ours"]) for r in flips) > 1.5  # type: ignore[arg-type]


def test_the_simulator_agrees_with_the_lobes(report: dict[str, object]) -> None:
    checks = _checks(report)
    for name in ("ad1", "ad0.05", "all"):
        assert checks[f"lobe.simulator_agreement_far.{name}"]["holds"], name


def test_the_drives_table_and_its_check_on_the_demo(report: dict[str, object]) -> None:
    checks = _checks(report)
    for name in (
        "lobe.drives.average_2ms_922hz_db",
        "lobe.demo.stable_cut_below_onset",
        "lobe.demo.chatter_develops_after_depth_step",
        "lobe.demo.chatter_stops_after_speed_change",
        "lobe.chain.axis_current_within_5pct",
        "lobe.chain.trace500_within_5pct",
        "lobe.chain.spindle_within_5pct",
    ):
        assert checks[name]["holds"], name
    rows = _rows(report)
    assert math.isinf(float(rows["drives.1000hz.average_2ms_db"]["ours"] or -math.inf))  # type: ignore[arg-type]


def test_the_zoa_gap_checks_report_their_numbers(report: dict[str, object]) -> None:
    # the issue's 5 % at a/D = 1 is not met on this benchmark (docs/chatter.md): the
    # checks must carry the measured gap, whether they hold or not
    checks = _checks(report)
    rows = _rows(report)
    gap = checks["lobe.zoa_within_5pct_ad1"]
    assert gap["value"] == pytest.approx(rows["ad1.zoa_gap.max_abs"]["ours"])
    assert gap["holds"] == (float(gap["value"]) <= 5.0)  # type: ignore[arg-type]
