"""Properties of the machining centre's interpolator, and its state through a checkpoint."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from common.state_io import load_state, save_state
from machine.centre import kernel as kn
from machine.centre.program import Block, Program, default_tools
from machine.centre.sim import MachiningCentre, trapezoid_time


def _moves(length: float, feed: float, direction: float) -> Program:
    x = length * math.cos(direction)
    y = length * math.sin(direction)
    blocks = (
        Block(10, "feed", (0.05 + x, 0.05 + y, 0.1), feed=feed),
        Block(20, "dwell", seconds=0.01),
    )
    return Program("O3", blocks, default_tools(), start=(0.05, 0.05, 0.1))


@settings(max_examples=25, deadline=None)
@given(
    length=st.floats(1e-5, 0.03),
    feed=st.floats(0.01, 0.3),
    direction=st.floats(0.0, 2 * math.pi),
    override=st.sampled_from([0.5, 0.8, 1.0, 1.2]),
)
def test_a_move_ends_exactly_on_its_target_within_its_speed_and_acceleration(
    length: float, feed: float, direction: float, override: float
) -> None:
    m = MachiningCentre(program=_moves(length, feed, direction), override_prob=0.0)
    s = m.set_overrides(m.initial_state(seed=0), feed=override)
    n = round(trapezoid_time(length, feed * override, 3.0) / 1e-4) + 50
    s, rec = m.step(s, n)
    on = rec.line == 10
    x, y = rec.signal("X.q_cmd")[on], rec.signal("Y.q_cmd")[on]
    # the block's last command is its target, to the rounding of the path parameter
    tx, ty = m.program.blocks[0].target[:2]  # type: ignore[index]
    assert abs(x[-1] - tx) < 1e-12 and abs(y[-1] - ty) < 1e-12
    p = np.hypot(np.diff(np.r_[0.05, x]), np.diff(np.r_[0.05, y])) / 1e-4
    assert p.max() <= feed * override * (1 + 1e-9)
    acc = np.diff(np.r_[0.0, p, 0.0]) / 1e-4
    assert np.abs(acc).max() <= 3.0 * (1 + 1e-6)
    # it takes the trapezoid's time (the discrete braking starts a little early and
    # creeps in the last samples: up to 1 ms longer)
    dt = on.sum() * 1e-4 - trapezoid_time(length, feed * override, 3.0)
    assert -2e-4 <= dt <= 1e-3


def test_the_state_goes_through_a_checkpoint_and_runs_on_the_same(tmp_path: Path) -> None:
    m = MachiningCentre()
    s = m.initial_state(seed=5)
    s, _ = m.step(s, 141_000)  # in T2's first side cut
    assert s.run is not None and s.run.cp[kn.CP_ACTIVE] == 1.0
    s, now = m.inject(s, "breakage", 0.3e-3, flute=2)
    s, _ = m.inject(s, "missing_tool", 0.5)  # waits for the next cut
    assert now and len(s.pending) == 1
    save_state(tmp_path / "centre.npz", s, kind="machining-centre", version=1)
    back, _ = load_state(tmp_path / "centre.npz", kind="machining-centre", version=1)
    _, a = m.step(s, 60_000)
    _, b = m.step(back, 60_000)
    assert np.array_equal(a.rows, b.rows) and np.array_equal(a.vb, b.vb)
    assert [e.kind for e in a.events] == [e.kind for e in b.events] == ["breakage", "missing_tool"]
