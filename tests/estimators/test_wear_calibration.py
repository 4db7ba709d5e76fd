"""Live wear from a machine's own labelled lives (issue 35 item 7), synthetic lives with
a known signal-wear relation; nothing here reads the real data."""

from __future__ import annotations

import numpy as np
import pytest

from estimators.errors import ParameterError
from estimators.wear.calibration import LabelledLife, MachineWear
from estimators.wear.hybrid import HybridConfig


def life(seed: int, machine: str = "lathe-1", kind: str = "lathe", n: int = 120) -> LabelledLife:
    rng = np.random.default_rng(seed)
    vb = np.linspace(0.0, rng.uniform(150, 300), n)
    y = 300.0 + rng.normal(0, 4) + 0.8 * vb + rng.normal(0, 6, n)
    return LabelledLife(machine, kind, seed, y[:, None], np.full(n, 2260.0), 0.0, float(vb[-1]))


def machine(**kw: object) -> MachineWear:
    cfgs = [HybridConfig("conditions", "linear", 1e-3), HybridConfig("none", "linear", None)]
    return MachineWear("lathe-1", "lathe", configs=cfgs, **kw)  # type: ignore[arg-type]


def test_uncalibrated_until_enough_lives_with_the_priors_interval() -> None:
    m = machine()
    first = life(1)
    e = m.estimate(first.x, first.feed)
    assert m.status == "uncalibrated" and e.status == "uncalibrated"
    assert np.all(e.lo <= e.vb) and np.all(e.vb <= e.hi)
    m.add_life(first)
    m.add_life(life(2))
    assert m.status == "uncalibrated"
    e2 = m.estimate(first.x, first.feed)
    # the prior's rate is now the lives' median rate
    rate = np.median([(lf.vb_end - lf.vb_start) / (len(lf.feed) - 1) for lf in m.lives])
    assert e2.vb[-1] == pytest.approx(rate * (len(first.feed) - 1))
    m.add_life(life(3))
    assert m.status == "calibrated"


def test_calibrated_estimate_tracks_a_new_tool_and_its_interval_covers() -> None:
    m = machine()
    for s in range(1, 6):
        m.add_life(life(s))
    new = life(42)
    e = m.estimate(new.x, new.feed, start_vb=0.0)
    truth = np.linspace(new.vb_start, new.vb_end, len(new.feed))
    assert e.status == "calibrated"
    assert float(np.mean(np.abs(e.vb - truth))) < 25.0
    assert float(np.mean((truth >= e.lo) & (truth <= e.hi))) > 0.8


def test_a_lathe_map_is_not_carried_to_a_mill_nor_to_another_machine() -> None:
    m = machine()
    with pytest.raises(ParameterError, match="kind"):
        m.add_life(life(1, kind="mill"))
    with pytest.raises(ParameterError, match="machine"):
        m.add_life(life(1, machine="lathe-2"))
    with pytest.raises(ParameterError, match="kind"):
        MachineWear("m", "grinder")
    with pytest.raises(ParameterError, match="vb_end"):
        LabelledLife("m", "lathe", 1, np.zeros((3, 1)), np.ones(3), 50.0, 10.0)
