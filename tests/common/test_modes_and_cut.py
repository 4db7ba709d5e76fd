"""The modal model and the cut geometry shared by the simulator and the lobes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from common.cut_geometry import CutGeometry, directional_integral, engagement
from common.errors import ParameterError
from common.modes import BENCHMARK_1DOF, ModalModel, Mode


def test_benchmark_mode_stiffness_and_resonant_receptance() -> None:
    m = BENCHMARK_1DOF.modes[0]
    assert m.stiffness == pytest.approx(0.03993 * (2 * math.pi * 922.0) ** 2)
    # at resonance the receptance is 1 / (i 2 zeta k)
    g = m.receptance(922.0)
    assert g.real == pytest.approx(0.0, abs=1e-12)
    assert abs(g) == pytest.approx(1.0 / (2 * 0.011 * m.stiffness), rel=1e-9)


def test_frf_adds_modes_along_their_directions() -> None:
    x = Mode.from_stiffness(500.0, 0.05, 1e6, 0.0)
    y = Mode.from_stiffness(700.0, 0.02, 2e6, 90.0)
    d = Mode.from_stiffness(900.0, 0.03, 3e6, 45.0, "workpiece")
    frf = ModalModel((x, y, d)).frf(600.0)
    half = 0.5 * d.receptance(600.0)
    assert frf[0, 0] == pytest.approx(x.receptance(600.0) + half)
    assert frf[1, 1] == pytest.approx(y.receptance(600.0) + half)
    assert frf[0, 1] == pytest.approx(half)
    assert frf[0, 1] == pytest.approx(frf[1, 0])
    many = ModalModel((x, y, d)).frf_many(np.array([100.0, 600.0]))
    assert many[1] == pytest.approx(frf)


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        ({"freq_hz": -1.0}, "freq_hz"),
        ({"damping": 1.0}, "damping"),
        ({"mass": 0.0}, "mass"),
        ({"direction_deg": math.nan}, "direction_deg"),
        ({"body": "spindle"}, "body"),
    ],
)
def test_bad_modes_are_named(kw: dict[str, object], match: str) -> None:
    args: dict[str, object] = {"freq_hz": 900.0, "damping": 0.02, "mass": 0.1}
    args.update(kw)
    with pytest.raises(ParameterError, match=match):
        Mode(**args)  # type: ignore[arg-type]


def test_a_modal_model_needs_modes() -> None:
    with pytest.raises(ParameterError, match="modes"):
        ModalModel(())
    with pytest.raises(ParameterError, match=r"modes\[0\]"):
        ModalModel(("a mode",))  # type: ignore[arg-type]


def test_engagement_of_up_and_down_milling() -> None:
    assert engagement(1.0, True) == pytest.approx((0.0, math.pi))
    assert engagement(1.0, False) == pytest.approx((0.0, math.pi))
    assert engagement(0.5, True) == pytest.approx((math.pi / 2, math.pi))
    assert engagement(0.5, False) == pytest.approx((0.0, math.pi / 2))


def test_directional_integral_matches_quadrature() -> None:
    lo, hi, kt, kn = 0.3, 2.4, 6e8, 2e8
    phi = np.linspace(lo, hi, 200001)
    s, c = np.sin(phi), np.cos(phi)
    w = np.array([kt * c + kn * s, kt * s - kn * c])
    v = np.array([s, -c])
    num = np.array([[np.trapezoid(w[i] * v[j], phi) for j in range(2)] for i in range(2)])
    assert directional_integral(lo, hi, kt, kn) == pytest.approx(num, rel=1e-8, abs=1.0)


def test_interval_averages_make_up_the_mean() -> None:
    for imm, down in ((1.0, True), (0.05, True), (0.3, False)):
        cut = CutGeometry(3, imm, down, 6e8, 2e8)
        parts = cut.interval_directional(37)
        assert parts.mean(axis=0) == pytest.approx(cut.mean_directional(), rel=1e-9, abs=1.0)


def test_full_immersion_mean_xx_is_n_kn_over_4() -> None:
    # Insperger-Stepan's h(t) averaged over a tooth period at a/D = 1: N Kn / 4
    cut = CutGeometry(2, 1.0, True, 6e8, 2e8)
    assert cut.mean_directional()[0, 0] == pytest.approx(2 * 2e8 / 4)


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        ({"n_flutes": 0}, "n_flutes"),
        ({"radial_immersion": 0.0}, "radial_immersion"),
        ({"radial_immersion": 1.5}, "radial_immersion"),
        ({"kt": 0.0}, "kt"),
        ({"kn": -1.0}, "kn"),
    ],
)
def test_bad_cuts_are_named(kw: dict[str, object], match: str) -> None:
    args: dict[str, object] = {
        "n_flutes": 2,
        "radial_immersion": 1.0,
        "down_milling": True,
        "kt": 6e8,
        "kn": 2e8,
    }
    args.update(kw)
    with pytest.raises(ParameterError, match=match):
        CutGeometry(**args)  # type: ignore[arg-type]
