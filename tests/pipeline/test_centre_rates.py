"""Where the machining centre's trace lets the DFO and the eccentricity loop see their
orders (issue 31 item 2): each tool's rotation and tooth passing against the Nyquist
frequency, and where a point-sampled trace folds what lies above it."""

from __future__ import annotations

import pytest

from machine.centre.program import default_program
from server.pipeline.centre_rates import alias, dfo_reason, eccentricity_reason, tool_orders


def test_alias_folds_into_the_first_nyquist_band() -> None:
    assert alias(200.0, 500.0) == 200.0
    assert alias(400.0, 500.0) == 100.0
    assert alias(1000.0 / 3.0, 500.0) == pytest.approx(500.0 / 3.0)
    assert alias(500.0, 500.0) == 0.0


def test_the_programs_tools_at_500_hz() -> None:
    orders = tool_orders(default_program(), 500.0)
    got = [(o.tool, o.flutes, o.rpm, o.tooth_seen) for o in orders]
    assert got == [(1, 4, 3000.0, True), (2, 3, 8000.0, False), (3, 2, 10000.0, False)]
    t1, t2, t3 = orders
    assert t1.samples_per_rev == 10.0 and t2.samples_per_rev == pytest.approx(3.75)
    assert t2.tooth_alias_hz == pytest.approx(100.0) and t2.max_rpm_for_tooth == 5000.0
    # a 2-flute tool at 10,000 rpm: 3 samples per revolution, its tooth passing folds
    # exactly onto its rotation (the runout's 1x)
    assert t3.tooth_alias_hz == pytest.approx(t3.rotation_hz)
    assert "T3's tooth passing (333 Hz) folds onto its own 1x (167 Hz)" in eccentricity_reason(
        default_program(), 500.0
    )
    why = dfo_reason(default_program(), 500.0)
    assert "T1's tooth passing (4 x 50 Hz = 200 Hz at 3000 rpm) lies below it" in why
    assert "T3's (2 x 167 Hz = 333 Hz at 10000 rpm) folds to 167 Hz" in why


@pytest.mark.parametrize(("rate", "seen"), [(1000.0, [1, 2, 3]), (2500.0, [1, 2, 3])])
def test_faster_traces_carry_every_tooth_passing(rate: float, seen: list[int]) -> None:
    orders = tool_orders(default_program(), rate)
    assert [o.tool for o in orders if o.tooth_seen] == seen
    assert "folds" not in dfo_reason(default_program(), rate)
    assert "folds onto" not in eccentricity_reason(default_program(), rate)
