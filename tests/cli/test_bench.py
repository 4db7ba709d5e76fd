"""`cutwatch bench`: group names derived one way, the headline realtime_factor is the
stage group's, the command's docstring lists every group."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from typing import Any

import pytest

from server.cli.commands import bench


def _bench(*args: str) -> dict[str, Any]:
    r = subprocess.run(
        [sys.executable, "-m", "server.cli.main", "bench", *args, "--quick", "--repeats", "1"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr
    doc: dict[str, Any] = json.loads(r.stdout)
    return doc


def test_group_names_are_hyphenated_and_derived_from_the_module_name() -> None:
    names = list(bench.groups())
    assert "residual-two-inertia" in names and "tool-wear" in names and "pipeline" in names
    for name in names:
        assert re.fullmatch(r"[a-z0-9]+(-[a-z0-9]+)*", name), name


def test_the_docstring_lists_exactly_the_groups() -> None:
    doc = bench.__doc__ or ""
    block = doc.split("Groups", 1)[1].split("\n\n", 1)[0]
    listed = [line.split()[0] for line in block.splitlines()[1:] if line.strip()]
    assert listed == sorted(bench.groups())


def test_the_top_level_realtime_factor_is_the_stage_groups() -> None:
    # pipeline runs first and reports its own realtime_factor: it must not be the headline
    doc = _bench("pipeline", "stage", "--json")
    assert doc["realtime_factor"] == doc["stage"]["realtime_factor"]
    assert doc["realtime_factor"] != doc["pipeline"]["realtime_factor"]
    assert doc["realtime_factor_of"].startswith("stage: ")
    assert doc["stage"]["configuration"] in doc["realtime_factor_of"]


def test_the_json_carries_the_reference_and_every_speed_as_a_ratio_to_it() -> None:
    doc = _bench("stage", "--json")
    ref = doc["reference"]
    assert ref["version"] >= 1 and ref["seconds"] > 0
    assert len(ref["runs_seconds"]) == 2  # --quick: one run before the groups, one after
    assert ref["spread"] >= 1.0
    ratios = doc["ratios"]["stage"]
    for key in ("offline_block_2500.realtime_factor", "live_block_125.realtime_factor"):
        assert ratios[key] == pytest.approx(doc["stage"][key] * ref["seconds"], rel=1e-12)
    cost = "live_block_125.per_block_ms.run_2s"
    assert ratios[cost] == pytest.approx(doc["stage"][cost] / ref["seconds"], rel=1e-12)
    assert doc["realtime_factor_ratio"] == ratios["realtime_factor"]


def test_duration_needs_one_group_with_a_soak() -> None:
    r = subprocess.run(
        [sys.executable, "-m", "server.cli.main", "bench", "stage", "--duration", "5"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 2
    assert "--duration" in r.stderr and "live" in r.stderr and "stage" in r.stderr


def test_without_the_stage_group_there_is_no_headline_and_it_says_why() -> None:
    doc = _bench("pipeline", "--json")
    assert "realtime_factor" not in doc
    assert "stage group was not run" in doc["realtime_factor_of"]
    assert doc["pipeline"]["realtime_factor"] > 0


def test_an_unknown_group_is_named_with_the_known_ones() -> None:
    r = subprocess.run(
        [sys.executable, "-m", "server.cli.main", "bench", "no-such-group", "--quick"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 2
    assert "no-such-group" in r.stderr and "residual-two-inertia" in r.stderr
    assert "Traceback" not in r.stderr


def test_the_pipeline_costs_estimation_apart_from_simulation_by_part() -> None:
    # one JSON document on stdout (json.loads of the whole of it); the children's output
    # and the progress on stderr
    doc = _bench("pipeline", "--json")["pipeline"]
    parts = ("stage", "effects", "dfo", "wear", "workpiece", "eccentricity", "process")
    for p in parts:
        assert doc[f"part.{p}.estimation_ms"] >= 0.0 and doc[f"part.{p}.simulation_ms"] >= 0.0
    # the stage's observers estimate; the workpiece only simulates; the process part both
    assert doc["part.stage.estimation_ms"] > 10 * doc["part.stage.simulation_ms"]
    assert doc["part.workpiece.simulation_ms"] > doc["part.workpiece.estimation_ms"]
    assert doc["part.process.simulation_ms"] > 0.0 and doc["part.process.estimation_ms"] > 0.0
    total = doc["cost.estimation_ms"] + doc["cost.simulation_ms"]
    assert total == pytest.approx(doc["cost.wall_ms"], rel=1e-6)


def test_the_upload_group_measures_the_loops_lag_beside_idle() -> None:
    # a real service, a real 20 MB upload (--quick): the figures are there and consistent
    # (the lag itself is a measurement, not judged here)
    doc = _bench("upload", "--json")["upload"]
    assert doc["runs"] == 1 and doc["upload_mb"] > 19.0 and doc["upload_rows"] > 400_000
    assert doc["lag_samples_per_upload"] >= 1
    assert 0.0 <= doc["loop_lag_p99_idle_ms"] <= doc["loop_lag_max_idle_ms"]
    assert 0.0 <= doc["loop_lag_p99_upload_ms"] <= doc["loop_lag_max_upload_ms"]
    assert doc["upload_mb_per_s"] == pytest.approx(doc["upload_mb"] / doc["upload_s"])


def test_against_runs_both_trees_in_turn_and_gives_every_figure_side_by_side() -> None:
    # the broker group: no kernels to compile in the other tree, the cheapest to run twice
    doc = _bench("broker", "--json", "--against", "HEAD")["broker"]
    ba = doc["before_after"]
    assert ba["ref"] == "HEAD" and len(ba["commit"]) == 40 and ba["runs"] == 1
    assert len(ba["figures"]) >= 4
    for key, row in ba["figures"].items():
        # the group's own figures are this tree's medians
        assert row["before"] > 0 and row["after"] == doc[key]
        assert row["after_over_before"] == pytest.approx(row["after"] / row["before"])
        assert row["before_spread"] == row["after_spread"] == 1.0  # one run each


def test_against_an_unknown_commit_is_refused_by_git() -> None:
    r = subprocess.run(
        [sys.executable, "-m", "server.cli.main", "bench", "pipeline", "--quick", "--repeats",
         "1", "--against", "no-such-ref-here"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert r.returncode != 0
    assert "--against 'no-such-ref-here': git archive failed" in r.stderr


def test_against_a_commit_without_the_group_names_it_before_measuring() -> None:
    # bench_centre.py came with the machining centre; its parent commit has no such group
    added = subprocess.run(
        ["git", "log", "--diff-filter=A", "--format=%H", "--",
         "server/experiments/benchmarks/bench_centre.py"],
        capture_output=True, text=True, check=False,
    ).stdout.split()  # fmt: skip
    if not added:
        pytest.skip("no git history of bench_centre.py in this checkout")
    r = subprocess.run(
        [sys.executable, "-m", "server.cli.main", "bench", "centre", "--quick", "--repeats",
         "1", "--against", f"{added[-1]}^"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert r.returncode == 2, r.stderr
    assert "no benchmark group 'centre' there" in r.stderr and "Traceback" not in r.stderr
    assert "warm-up" not in r.stderr  # refused before anything ran


def test_side_by_side_gives_medians_spreads_and_the_ratio_of_the_figures_both_report() -> None:
    from server.experiments.bench_against import side_by_side, split

    run = split({"ms": 10.0, "n": 3, "ok": True, "cfg": "x", "runs": [1.0, 2.0]})
    assert run.figures == {"ms": 10.0, "n": 3.0} and run.labels == {"ok": "True", "cfg": "x"}
    runs = {
        "before": [run.figures | {"old": 1.0}, {"ms": 14.0, "n": 3.0, "old": 2.0},
                   {"ms": 12.0, "n": 3.0, "old": 1.0}],
        "after": [{"ms": 6.0, "n": 3.0}, {"ms": 9.0, "n": 3.0}, {"ms": 8.0, "n": 3.0}],
    }  # fmt: skip
    table = side_by_side(runs)
    assert set(table) == {"ms", "n"}  # a figure only one tree has is not compared
    assert table["ms"] == {
        "before": 12.0, "before_spread": 1.4, "after": 8.0, "after_spread": 1.5,
        "after_over_before": pytest.approx(8.0 / 12.0),
    }  # fmt: skip
    assert table["n"]["after_over_before"] == 1.0
