"""The reference workload of ``cutwatch bench`` (issue 22, item 6): self-contained, and
the rule that turns a figure into its ratio."""

from __future__ import annotations

import ast
import math
from pathlib import Path

import pytest

from server.experiments import bench_reference as ref


def test_the_workload_calls_nothing_of_the_project() -> None:
    # a faster project must never move the yardstick
    tree = ast.parse(Path(ref.__file__).read_text(encoding="utf-8"))
    imported: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            imported.update(a.name.split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            imported.add(node.module.split(".")[0])
    assert imported <= {"__future__", "math", "statistics", "time", "dataclasses", "numpy", "numba"}


def test_one_run_times_three_parts_that_add_up() -> None:
    r = ref.run_once()
    assert r["cpu_seconds"] > 0
    parts = r["numba_seconds"] + r["numpy_seconds"] + r["python_seconds"]
    assert all(r[k] > 0 for k in ("numba_seconds", "numpy_seconds", "python_seconds"))
    assert r["seconds"] == pytest.approx(parts, rel=1e-9)


def test_the_parts_compute_the_same_every_time() -> None:
    import numpy as np

    a, b = np.zeros(256), np.zeros(256)
    assert ref._kernel(20_000, a) == ref._kernel(20_000, b)
    assert ref._numpy_part(7) == ref._numpy_part(7)
    assert ref._python_part(500) == ref._python_part(500)


def test_speeds_are_multiplied_and_costs_divided_by_the_reference() -> None:
    assert ref.normalise("offline_block_2500.realtime_factor", 300.0, 2.0) == 600.0
    assert ref.normalise("analysis_samples_per_second", 1e5, 0.5) == 5e4
    assert ref.normalise("analysis_seconds", 9.0, 1.5) == 6.0
    assert ref.normalise("live_block_125.per_block_ms.run_2s", 0.3, 0.5) == 0.6
    assert ref.normalise("monitor_pass_us", 100.0, 2.0) == 50.0
    assert ref.normalise("cpu_percent_one_core", 5.0, 0.5) == 10.0
    assert ref.normalise("cpu_pct_one_core.services", 6.0, 2.0) == 3.0


def test_latencies_sizes_and_counts_are_not_normalised() -> None:
    for key in (
        "frame_latency_p99_ms",
        "loop_lag_p99_ms",
        "rss_mb",
        "rss_slope_mb_per_min",
        "window_s",
        "samples",
        "dropped_frames",
    ):
        assert ref.normalise(key, 3.0, 2.0) is None, key
    assert ref.normalise("analysis_seconds", math.nan, 2.0) is None


def test_the_reference_is_the_median_of_its_runs_and_shows_their_spread() -> None:
    runs = [
        {
            "seconds": s,
            "cpu_seconds": 0.5,
            "numba_seconds": s / 3,
            "numpy_seconds": s / 3,
            "python_seconds": s / 3,
        }
        for s in (1.0, 1.2, 3.0)
    ]
    d = ref.Reference(runs).as_dict()
    assert d["seconds"] == 1.2 and d["spread"] == 3.0
    assert d["cpu_seconds"] == 0.5 and d["wall_over_cpu"] == pytest.approx(2.4)
    assert d["version"] == ref.REFERENCE_VERSION and d["runs_seconds"] == [1.0, 1.2, 3.0]
