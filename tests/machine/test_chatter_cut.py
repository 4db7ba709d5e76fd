"""The regenerative cut on a rigid machine (machine/chatter.py, machine/regeneration.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from common.cut_geometry import CutGeometry
from common.errors import ParameterError
from common.modes import BENCHMARK_1DOF, ModalModel, Mode
from machine import regeneration as rg
from machine.chatter import ChatterCut, ChatterCutParams, growth_over, per_revolution

SLOT = CutGeometry(2, 1.0, True, 6e8, 2e8)
#: the SD boundary of the benchmark at 10000 rpm, a/D = 1 (docs/chatter.md): 0.3226 mm
BOUNDARY_10K = 0.3226e-3


def test_the_exact_step_of_a_free_mode_is_its_decaying_cosine() -> None:
    m = Mode(500.0, 0.05, 0.2)
    dt = 1e-5
    p = rg.discretise(ModalModel((m,)), dt)[0]
    step = np.array([[p[0], p[1]], [p[2], p[3]]])
    x = np.array([1.0, 0.0])
    for _ in range(1000):
        x = step @ x
    t = 1000 * dt
    wd = m.omega * math.sqrt(1 - m.damping**2)
    z = m.damping * m.omega
    exact = math.exp(-z * t) * (math.cos(wd * t) + z / wd * math.sin(wd * t))
    assert x[0] == pytest.approx(exact, rel=1e-9)


def test_a_stiff_tool_cuts_the_nominal_chip() -> None:
    # mean X force on the tool at a/D = 1, straight flutes, no vibration: a c N Kn / 4
    stiff = ModalModel((Mode.from_stiffness(20000.0, 0.05, 1e11, 0.0),))
    p = ChatterCutParams(stiff, SLOT, 1e-3, 6000.0, feed_per_tooth=0.1e-3)
    cut = ChatterCut(p)
    cut.run_revolutions(2)
    rec = cut.run_revolutions(10)
    assert float(np.mean(rec.fx)) == pytest.approx(-1e-3 * 0.1e-3 * 2 * 2e8 / 4, rel=2e-3)
    assert float(np.max(np.abs(rec.qx))) < 1e-8


def test_no_depth_no_force_no_vibration() -> None:
    rec = ChatterCut(ChatterCutParams(BENCHMARK_1DOF, SLOT, 0.0, 8000.0)).run_revolutions(3)
    assert np.all(rec.fx == 0.0) and np.all(rec.qx == 0.0)


def test_stable_below_and_chatter_above_the_boundary() -> None:
    below = growth_over(ChatterCutParams(BENCHMARK_1DOF, SLOT, 0.8 * BOUNDARY_10K, 10000.0))
    above = growth_over(ChatterCutParams(BENCHMARK_1DOF, SLOT, 1.25 * BOUNDARY_10K, 10000.0))
    assert below.stable and below.growth < 0.2
    assert not above.stable and above.growth > 1.5
    # Hopf chatter near the natural frequency (SD: 930 Hz at this speed)
    assert above.frequency_hz == pytest.approx(931.0, abs=3.0)


def test_chatter_saturates_when_the_tool_leaves_the_cut() -> None:
    cut = ChatterCut(ChatterCutParams(BENCHMARK_1DOF, SLOT, 2 * BOUNDARY_10K, 10000.0))
    rec = cut.run_revolutions(80)
    a, f = per_revolution(rec)
    assert a[-1] > f[-1]  # developed
    assert np.std(a[-10:]) < 0.05 * np.mean(a[-10:])  # a limit cycle, not a blow-up
    last = rec.t > rec.t[-1] - 0.01
    assert np.sum(rec.in_cut[last]) < 0.9 * np.sum(rec.engaged[last])
    assert cut.truth.onset_t is not None and cut.truth.developed_t is not None
    assert cut.truth.onset_t <= cut.truth.developed_t


def test_chatter_stops_when_the_speed_moves_to_a_stable_lobe() -> None:
    # 0.5 mm chatters at 10000 rpm (boundary 0.32 mm) and is stable at 20000 (1.42 mm)
    cut = ChatterCut(ChatterCutParams(BENCHMARK_1DOF, SLOT, 0.5e-3, 10000.0))
    rec = cut.run_revolutions(60)
    assert rec.amp_nonforced[-1] > rec.amp_forced[-1]
    cut.set_spindle_rpm(20000.0)
    rec = cut.run_revolutions(60)
    assert rec.amp_nonforced[-1] < 0.1 * rec.amp_forced[-1]


def test_chatter_stops_when_the_depth_steps_down() -> None:
    cut = ChatterCut(ChatterCutParams(BENCHMARK_1DOF, SLOT, 0.5e-3, 10000.0))
    cut.run_revolutions(60)
    cut.set_axial_depth(0.15e-3)
    rec = cut.run_revolutions(60)
    assert rec.amp_nonforced[-1] < 0.1 * rec.amp_forced[-1]


def test_a_slower_speed_grows_the_memory_and_keeps_cutting() -> None:
    cut = ChatterCut(ChatterCutParams(BENCHMARK_1DOF, SLOT, 0.2e-3, 20000.0))
    cut.run_revolutions(5)
    n = cut._hist.shape[0]
    cut.set_spindle_rpm(1000.0)
    assert cut._hist.shape[0] > n
    rec = cut.run_revolutions(3)
    assert np.all(np.isfinite(rec.fx)) and float(np.mean(rec.fx)) < 0.0


def test_runout_gives_uneven_flutes_and_no_false_onset() -> None:
    p = ChatterCutParams(BENCHMARK_1DOF, SLOT, 0.5 * BOUNDARY_10K, 10000.0, runout=(10e-6, 0.0))
    cut = ChatterCut(p)
    cut.run_revolutions(40)
    rec = cut.run_revolutions(2)
    # the flute with the larger radius cuts more: a once-per-revolution force
    spec = np.abs(np.fft.rfft(rec.fx - rec.fx.mean()))
    f = np.fft.rfftfreq(rec.fx.size, cut.dt)
    once = spec[np.argmin(np.abs(f - 10000.0 / 60.0))]
    assert once > 0.05 * np.max(spec)
    assert rec.amp_nonforced[-1] < 0.1 * rec.amp_forced[-1]


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        ({"axial_depth": -1e-3}, "axial_depth"),
        ({"spindle_rpm": 100.0}, "spindle_rpm"),
        ({"feed_per_tooth": 0.0}, "feed_per_tooth"),
        ({"helix_deg": 70.0}, "helix_deg"),
        ({"n_layers": 0}, "n_layers"),
        ({"runout": (1e-6,)}, "runout"),
        ({"memory_passes": -1}, "memory_passes"),
        ({"steps_per_mode_period": 8}, "steps_per_mode_period"),
        ({"modal": "a tool"}, "modal"),
    ],
)
def test_bad_parameters_are_named(kw: dict[str, object], match: str) -> None:
    args: dict[str, object] = {
        "modal": BENCHMARK_1DOF,
        "cut": SLOT,
        "axial_depth": 1e-3,
        "spindle_rpm": 10000.0,
    }
    args.update(kw)
    with pytest.raises(ParameterError, match=match):
        ChatterCutParams(**args)  # type: ignore[arg-type]


def test_bad_steps_are_named() -> None:
    cut = ChatterCut(ChatterCutParams(BENCHMARK_1DOF, SLOT, 1e-4, 10000.0))
    with pytest.raises(ParameterError, match="'n'"):
        cut.step(-1)
    with pytest.raises(ParameterError, match="spindle_rpm"):
        cut.set_spindle_rpm(1e6)
    with pytest.raises(ParameterError, match="axial_depth"):
        cut.set_axial_depth(-1.0)
