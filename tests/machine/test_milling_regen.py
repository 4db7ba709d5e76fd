"""Seed 003's milling machine with a flexible tool (machine/milling_regen.py)."""

from __future__ import annotations

import numpy as np
import pytest

from common.errors import ParameterError
from common.modes import ModalModel, Mode
from machine.milling import MillingMachine, MillingParams
from machine.milling_regen import DEMO_STRUCTURE
from machine.spindle import SpindleParams

#: a tool far stiffer than the cut: the flexible machine must cut as the rigid one does
STIFF = ModalModel(
    (Mode.from_stiffness(8000.0, 0.05, 5e10, 0.0), Mode.from_stiffness(8000.0, 0.05, 5e10, 90.0))
)


def test_a_stiff_structure_cuts_as_the_rigid_machine() -> None:
    mp = MillingParams(eccentricity=0.0)
    rigid = MillingMachine(mp)
    flex = MillingMachine(mp, structure=STIFF)
    n = round(4 * rigid.samples_per_revolution())
    a = rigid.step(n)
    b = flex.step(n)
    last = slice(n // 2, n)
    for k in ("fx", "fy", "ix", "iy"):
        ra, rb = getattr(a, k)[last], getattr(b, k)[last]
        assert float(np.mean(rb)) == pytest.approx(float(np.mean(ra)), rel=0.005, abs=1e-3)
        assert float(np.ptp(rb)) == pytest.approx(float(np.ptp(ra)), rel=0.05)
    assert a.chatter is None and b.chatter is not None
    assert rigid.structure is None and flex.structure is STIFF and flex.substeps > 1


def test_the_surface_memory_removes_the_rigid_machines_phantom_chip() -> None:
    # 20 um eccentricity: near the up-milling entry the short flute cuts nothing, and the
    # next meets the surface two flutes back; the rigid machine's chip (seed003 (4), one
    # flute back) counts a chip there that is not
    mp = MillingParams(eccentricity=20e-6)
    rigid = MillingMachine(mp)
    flex = MillingMachine(mp, structure=STIFF)
    n = round(4 * rigid.samples_per_revolution())
    fa = float(np.mean(rigid.step(n).fx[n // 2 :]))
    fb = float(np.mean(flex.step(n).fx[n // 2 :]))
    assert fb < fa


def test_the_spindle_current_carries_the_cutting_torque() -> None:
    m = MillingMachine(MillingParams(), structure=STIFF, spindle=SpindleParams(torque_constant=0.4))
    m.step(round(6 * m.samples_per_revolution()))
    rec = m.step(round(4 * m.samples_per_revolution()))
    c = rec.chatter
    assert c is not None
    mean_cut = float(np.mean(c["cut_torque"]))
    assert mean_cut > 0.0
    # the motor holds the cut and the bearings' friction (b w) at the set speed
    friction = SpindleParams().viscous * float(np.mean(c["spindle_speed"]))
    assert float(np.mean(c["spindle_current"])) == pytest.approx(
        (mean_cut + friction) / 0.4, rel=0.01
    )
    assert float(np.mean(c["spindle_power"])) == pytest.approx(
        float(np.mean(c["spindle_torque"] * c["spindle_speed"])), rel=1e-9
    )


def test_seed003_cases_are_stable_on_the_demo_tool_and_4mm_chatters() -> None:
    stable = MillingMachine(MillingParams(eccentricity=5e-6), structure=DEMO_STRUCTURE)
    stable.step(2500)
    c = stable.step(1000).chatter
    assert c is not None and c["amp_nonforced"][-1] < 0.1 * c["amp_forced"][-1]
    deep = MillingMachine(
        MillingParams(eccentricity=5e-6, axial_depth=4e-3), structure=DEMO_STRUCTURE
    )
    deep.step(2500)
    c = deep.step(500).chatter
    assert c is not None and c["amp_nonforced"][-1] >= c["amp_forced"][-1]
    assert deep.chatter_truth.developed_t is not None
    assert 1150.0 < deep.chatter_truth.frequency() < 1300.0  # near the tool's 1200 Hz modes


def test_a_flexible_machine_needs_a_speed_its_memory_reaches() -> None:
    m = MillingMachine(MillingParams(), structure=DEMO_STRUCTURE)
    with pytest.raises(ParameterError, match="spindle_rpm"):
        m.set_spindle_rpm(100.0)
    with pytest.raises(ParameterError, match="structure"):
        MillingMachine(MillingParams(), structure="a tool")  # type: ignore[arg-type]
