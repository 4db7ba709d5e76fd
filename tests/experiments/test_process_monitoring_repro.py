"""`cutwatch reproduce process-monitoring --quick`: the Monte Carlo's contract.

The quick run (4 clear and 2 edge events per kind, 2 breakages with the canceller, 3
event-free minutes) cannot reach the intervals the full run's checks ask for (4 events
give a 95 % lower bound of 0.40); it must still find every clear event in time, raise no
false alarm, and hold the canceller while a breakage is suspected.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from server.experiments import confidence
from server.experiments.reproduction import Reproduction
from server.experiments.reproductions import process_monitoring as pm


@pytest.fixture(scope="module")
def quick(tmp_path_factory: pytest.TempPathFactory) -> tuple[Reproduction, Path]:
    plots = tmp_path_factory.mktemp("plots")
    return pm.run(quick=True, plot_dir=plots, progress=False), plots


def _row(rep: Reproduction, name: str) -> float:
    return rep.row(name).ours


def test_every_clear_event_is_found_in_time(quick: tuple[Reproduction, Path]) -> None:
    rep, _ = quick
    for kind in ("breakage", "collision", "missing_tool"):
        assert _row(rep, f"{kind}.clear.detection") == 1.0
        assert _row(rep, f"{kind}.clear.alarms_before_event") == 0
    assert _row(rep, "breakage.clear.delay_p95") <= pm.TARGET_BREAKAGE_REVS
    assert _row(rep, "collision.clear.delay_p95") <= pm.TARGET_COLLISION_S
    assert _row(rep, "missing_tool.clear.delay_p95") <= 1.0
    held = next(c for c in rep.checks if c.name == "breakage.canceller.esc_held_until_alarm")
    assert held.holds


def test_no_false_alarm_in_the_event_free_minutes(quick: tuple[Reproduction, Path]) -> None:
    rep, _ = quick
    for det in ("breakage", "collision", "missing_tool"):
        assert _row(rep, f"false_alarms.{det}") == 0.0
    assert _row(rep, "free.max_force_over_extreme") < 1.0
    assert _row(rep, "free.min_mean_over_lower") > 1.0
    assert _row(rep, "free.max_pattern_over_limit") < 1.0


def test_checks_use_the_interval_bounds(quick: tuple[Reproduction, Path]) -> None:
    rep, plots = quick
    det = next(c for c in rep.checks if c.name == "breakage.clear.detection_lower_95 >= 0.99")
    # 4 of 4: the one-sided Clopper-Pearson lower bound is 0.05 ** (1 / 4)
    assert det.value == pytest.approx(0.05**0.25) and not det.holds
    assert (plots / "process_monitoring_delays.png").stat().st_size > 10_000


def test_the_run_sizes_reach_the_targets_bounds() -> None:
    # the clear events and the event-free hours are enough for the one-sided bounds
    assert pm.N_CLEAR >= confidence.events_for(pm.TARGET_DETECTION)
    assert pm.FREE_HOURS >= confidence.hours_for(pm.TARGET_FALSE_PER_HOUR)


def test_cli_lists_the_experiment() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "server.cli.main", "reproduce", "--list"],
        capture_output=True,
        text=True,
        check=True,
    )
    assert "process-monitoring" in out.stdout
