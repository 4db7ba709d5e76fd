"""Stability lobes: the zero-order approximation and the semi-discretization against closed
forms and against each other."""

from __future__ import annotations

import math

import numpy as np
import pytest

from common.cut_geometry import CutGeometry
from common.errors import ParameterError
from common.modes import BENCHMARK_1DOF, ModalModel, Mode
from estimators.chatter.lobes import first_crossing, intervals_for, lobe_chart, sd_boundary
from estimators.chatter.sd import Multiplier, SemiDiscretization, largest_eigenvalue
from estimators.chatter.zoa import zoa_boundary, zoa_chart, zoa_lobes

SLOT = CutGeometry(2, 1.0, True, 6e8, 2e8)


def test_zoa_minimum_is_the_closed_form_of_one_mode() -> None:
    # 1-DOF: a_lim = -1 / (2 A0xx Re G), smallest where Re G = -1 / (4 k zeta (1 + zeta))
    mode = BENCHMARK_1DOF.modes[0]
    a0 = SLOT.mean_directional()[0, 0]
    closed = 2.0 * mode.stiffness * mode.damping * (1.0 + mode.damping) / a0
    lobes = zoa_lobes(BENCHMARK_1DOF, SLOT, n_freq=40000, freq_range=(900.0, 960.0))
    lowest = min(float(np.nanmin(lb.depth)) for lb in lobes)
    assert lowest == pytest.approx(closed, rel=1e-4)


def test_zoa_boundary_lies_on_a_lobe_and_has_its_frequency() -> None:
    lobes = zoa_lobes(BENCHMARK_1DOF, SLOT)
    depth, freq = zoa_boundary(lobes, 10000.0)
    assert math.isfinite(depth) and 0.0 < depth < 1e-3
    # the chatter frequency of a 1-DOF Hopf lobe lies above the natural frequency
    assert 922.0 < freq < 1000.0
    d2, _ = zoa_chart(BENCHMARK_1DOF, SLOT, np.array([10000.0]))
    assert d2[0] == pytest.approx(depth)


def test_sd_free_structure_multiplier_is_its_decay_over_a_tooth_period() -> None:
    # depth 0: the multipliers are exp(lambda tau), |mu| = exp(-zeta w_n tau)
    mode = BENCHMARK_1DOF.modes[0]
    sd = SemiDiscretization(BENCHMARK_1DOF, SLOT, 40)
    tau = SLOT.tooth_period(8000.0)
    assert sd.spectral_radius(8000.0, 0.0) == pytest.approx(
        math.exp(-mode.damping * mode.omega * tau), rel=1e-9
    )


@pytest.mark.parametrize("immersion", [1.0, 0.05])
def test_sd_of_the_averaged_system_is_the_zoa(immersion: float) -> None:
    cut = CutGeometry(2, immersion, True, 6e8, 2e8)
    for rpm in (7000.0, 16000.0):
        m = intervals_for(BENCHMARK_1DOF, cut, rpm)
        sd = SemiDiscretization(BENCHMARK_1DOF, cut, m, averaged=True)
        z = zoa_chart(BENCHMARK_1DOF, cut, np.array([rpm]), n_freq=20000)[0][0]
        assert sd_boundary(sd, rpm).depth == pytest.approx(z, rel=5e-3)


def test_sd_converges_at_second_order() -> None:
    d = [
        sd_boundary(SemiDiscretization(BENCHMARK_1DOF, SLOT, m), 8000.0).depth
        for m in (50, 100, 200)
    ]
    c1 = abs(d[1] - d[0])
    c2 = abs(d[2] - d[1])
    assert c2 < 0.35 * c1  # halving the step quarters the change (second order)


def test_flip_lobes_appear_at_low_immersion() -> None:
    cut = CutGeometry(2, 0.05, True, 6e8, 2e8)
    sd = SemiDiscretization(BENCHMARK_1DOF, cut, intervals_for(BENCHMARK_1DOF, cut, 16000.0))
    b = sd_boundary(sd, 16000.0)
    assert b.kind == "flip"
    z = zoa_chart(BENCHMARK_1DOF, cut, np.array([16000.0]))[0][0]
    assert z > 1.5 * b.depth  # the ZOA misses the period-doubling lobe
    # period doubling chatters at half the tooth frequency's odd multiples
    f = sd.chatter_frequency(16000.0, 1.01 * b.depth)
    tooth = 2 * 16000.0 / 60.0
    assert (f / tooth - 0.5) % 1.0 == pytest.approx(0.0, abs=1e-6)


def test_two_directions_make_a_two_by_two_problem() -> None:
    xy = ModalModel(
        (Mode.from_stiffness(1200, 0.02, 8e6, 0.0), Mode.from_stiffness(1200, 0.02, 8e6, 90.0))
    )
    cut = CutGeometry(4, 0.2, False, 700e6, 210e6)
    sd = SemiDiscretization(xy, cut, 100)
    z = zoa_chart(xy, cut, np.array([9000.0]))[0][0]
    b = sd_boundary(sd, 9000.0).depth
    assert b == pytest.approx(z, rel=0.2)  # a/D 0.2: the ZOA is close, not exact
    assert sd.monodromy(9000.0, b).shape == (2 * 2 + 100 * 2,) * 2


def test_first_crossing_finds_a_threshold_and_reports_none() -> None:
    assert first_crossing(lambda x: x >= 0.37, 0.01, 10.0, rtol=1e-6) == pytest.approx(
        0.37, rel=2e-6
    )
    assert first_crossing(lambda x: x >= 0.37, 0.5, 10.0) == 0.5
    assert math.isinf(first_crossing(lambda x: False, 0.01, 10.0))


def test_largest_eigenvalue_arpack_agrees_with_lapack() -> None:
    rng = np.random.default_rng(3)
    a = rng.normal(size=(150, 150)) / 30.0
    dense = np.linalg.eigvals(a)
    assert abs(largest_eigenvalue(a)) == pytest.approx(np.max(np.abs(dense)), rel=1e-9)


def test_multiplier_kinds() -> None:
    assert Multiplier(1.2, math.pi).kind == "flip"
    assert Multiplier(1.2, -math.pi).kind == "flip"
    assert Multiplier(1.2, 0.0).kind == "fold"
    assert Multiplier(1.2, 1.0).kind == "hopf"


def test_chart_and_interval_rule() -> None:
    ch = lobe_chart(BENCHMARK_1DOF, SLOT, np.array([6000.0, 15000.0]))
    assert ch.sd_depth.shape == (2,) and np.all(np.isfinite(ch.sd_depth))
    assert ch.gap() == pytest.approx(ch.zoa_depth / ch.sd_depth - 1.0)
    # slow speeds put more vibration periods in a tooth period: more intervals
    assert intervals_for(BENCHMARK_1DOF, SLOT, 5000.0) > intervals_for(
        BENCHMARK_1DOF, SLOT, 20000.0
    )


def test_bad_inputs_are_named() -> None:
    with pytest.raises(ParameterError, match="intervals"):
        SemiDiscretization(BENCHMARK_1DOF, SLOT, 1)
    with pytest.raises(ParameterError, match="depth"):
        SemiDiscretization(BENCHMARK_1DOF, SLOT, 10).monodromy(8000.0, -1.0)
    with pytest.raises(ParameterError, match="rpm"):
        SemiDiscretization(BENCHMARK_1DOF, SLOT, 10).monodromy(0.0, 1e-3)
    with pytest.raises(ParameterError, match="rpms"):
        lobe_chart(BENCHMARK_1DOF, SLOT, np.array([]))
    with pytest.raises(ParameterError, match="freq_range"):
        zoa_lobes(BENCHMARK_1DOF, SLOT, freq_range=(100.0, 50.0))
    with pytest.raises(ParameterError, match="lo/hi/ratio"):
        first_crossing(lambda x: True, 1.0, 0.5)


@pytest.mark.parametrize(
    ("modal", "cut", "rpm"),
    [
        (BENCHMARK_1DOF, CutGeometry(2, 0.5, False, 6e8, 2e8), 9000.0),
        (
            ModalModel(
                (
                    Mode.from_stiffness(1200, 0.02, 8e6, 0.0),
                    Mode.from_stiffness(1000, 0.03, 6e6, 90.0),
                )
            ),
            CutGeometry(3, 0.3, False, 700e6, 210e6),
            7000.0,
        ),
    ],
    ids=["1dof-up-half", "2dof-up-3flutes"],
)
def test_up_milling_lobes_agree_with_the_simulator(
    modal: ModalModel, cut: CutGeometry, rpm: float
) -> None:
    # the grid of the reproduction is the benchmark's down-milling; here up-milling, and
    # two directions with three flutes, each 20 % either side of the SD boundary
    from machine.chatter import ChatterCutParams, growth_over

    sd = SemiDiscretization(modal, cut, intervals_for(modal, cut, rpm))
    b = sd_boundary(sd, rpm).depth
    assert growth_over(ChatterCutParams(modal, cut, 0.8 * b, rpm)).stable
    assert not growth_over(ChatterCutParams(modal, cut, 1.2 * b, rpm)).stable
