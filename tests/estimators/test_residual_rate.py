"""The rate-dependent choices of the residual loop (issue 18 item 2): kHz logs keep the
benchmark's pipeline; lower rates keep its proportions; at 10 Hz only static maps."""

from __future__ import annotations

import pytest

from estimators.errors import ParameterError
from estimators.idim import IdimParams
from estimators.residual.rate import LOW_RATE_FAMILIES, rate_plan


@pytest.mark.parametrize("ts", [1e-3, 4e-4, 1e-4])
def test_khz_logs_keep_the_benchmark_pipeline(ts: float) -> None:
    plan = rate_plan(ts)
    assert plan.idim == IdimParams()
    assert plan.families is None and plan.not_identifiable == {} and plan.filter_position


@pytest.mark.parametrize(
    ("ts", "cutoff", "dec"), [(2e-3, 50.0, 5), (5e-3, 20.0, 2), (0.01, 10.0, 1)]
)
def test_lower_rates_keep_the_benchmark_proportions(ts: float, cutoff: float, dec: int) -> None:
    plan = rate_plan(ts)
    assert plan.idim.cutoff_hz == pytest.approx(cutoff)
    assert plan.idim.decimation == dec
    assert plan.families is None  # 100 Hz and up: every family


def test_ten_hertz_offers_friction_and_load_only_and_says_why() -> None:
    plan = rate_plan(0.1, velocity_given=True)
    assert plan.families == LOW_RATE_FAMILIES
    assert {"stribeck", "coulomb_asymmetry", "position_friction", "load"} <= set(plan.families)
    for name in ("inertia", "position_periodic", "position_harmonics", "harmonic", "delay"):
        assert name not in plan.families
        assert "Hz" in plan.not_identifiable[name] or "ms" in plan.not_identifiable[name]
    assert not plan.filter_position and plan.idim.decimation == 1
    assert "only static maps" in plan.note


@pytest.mark.parametrize("ts", [0.0, -1.0, float("nan"), 2.0, 1e-6])
def test_rates_outside_the_range_are_refused(ts: float) -> None:
    with pytest.raises(ParameterError, match="sample_time"):
        rate_plan(ts)
