"""The milling model with eccentricity and the X/Y feed drives (seed 003 eq. 1-7)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimators.esc import spindle_harmonic
from machine.errors import ParameterError
from machine.feed_drives import AxisParams, FeedDriveParams, FeedDrives
from machine.milling import MillingMachine, MillingParams


def _last_rev(
    machine: MillingMachine, revs: int, a_m: float = 0.0, theta_m: float = 0.0
) -> dict[str, np.ndarray]:
    n = round(machine.samples_per_revolution())
    rec = None
    for _ in range(revs):
        rec = machine.step(n, a_m, theta_m)
    assert rec is not None
    return {
        "fx": rec.fx,
        "fy": rec.fy,
        "psi": rec.psi,
        "x": rec.x,
        "y": rec.y,
        "rx": rec.rx,
        "ry": rec.ry,
    }


def test_zero_eccentricity_has_no_spindle_harmonic() -> None:
    """Without eccentricity the force repeats every tooth: no 1x component."""
    m = MillingMachine(MillingParams(eccentricity=0.0))
    r = _last_rev(m, 6)
    for f in (r["fx"], r["fy"]):
        assert np.ptp(f) > 20.0  # there is a cut
        assert abs(spindle_harmonic(f, r["psi"])) < 1e-9 * np.abs(f).max()
    # and the tooth-passing harmonic is there
    c4 = 2 / r["fx"].size * np.sum(r["fx"] * np.exp(-4j * r["psi"]))
    assert abs(c4) > 5.0


def _stiff_machine(p: MillingParams) -> MillingMachine:
    # carriages so heavy that the cutting force moves them by picometres: the tool
    # follows the commanded path, as the analytic estimate assumes
    ax = AxisParams(mass=1e8, viscous=0.0)
    return MillingMachine(p, FeedDriveParams(x=ax, y=ax, sample_time=2e-5))


def _analytic_1x(p: MillingParams) -> tuple[complex, complex]:
    r"""Small-eccentricity estimate of the 1x force phasors (X, Y), in closed form.

    Linear in the chip change :math:`\Delta r_{j,l} = \epsilon[\cos\beta - \cos(\beta -
    2\pi/N)]`, :math:`\beta = \theta_\epsilon + \pi/2 + 2\pi j/N + \lambda_l` (eq. 3-4 in
    our frame); each flute-layer contributes :math:`dz\,\Delta r\,e^{-j(2\pi j/N +
    \lambda_l)}\int_{\phi_{st}}^{\phi_{ex}} k(\phi) e^{-j\phi} d\phi / \pi`.
    """
    st_, ex = p.engagement()

    def integ(f_cos: float, f_sin: float) -> complex:
        # int (f_cos cos(phi) + f_sin sin(phi)) e^{-j phi} dphi over the window
        def prim(x: float) -> complex:
            c = x / 2 + np.exp(-2j * x) / (-4j)  # int cos e^{-j}
            s = (x - np.exp(-2j * x) / (-2j)) / (2j)  # int sin e^{-j}
            return complex(f_cos * c + f_sin * s)

        return prim(ex) - prim(st_)

    ix = integ(p.k_tc, p.k_rc)  # workpiece F_x per unit chip: K_tc cos + K_rc sin
    iy = integ(-p.k_rc, p.k_tc)  # F_y: K_tc sin - K_rc cos
    pitch = 2 * math.pi / p.n_flutes
    dz = p.axial_depth / p.n_layers
    th = math.radians(p.eccentricity_deg)
    fx = fy = 0j
    for j in range(p.n_flutes):
        for lag in p.layer_lags():
            beta = th + math.pi / 2 + j * pitch + lag
            dr = p.eccentricity * (math.cos(beta) - math.cos(beta - pitch))
            w = dz * dr * np.exp(-1j * (j * pitch + lag)) / math.pi
            fx += w * ix
            fy += w * iy
    return complex(fx), complex(fy)


@pytest.mark.parametrize("down", [False, True])
def test_one_x_component_matches_small_eccentricity_estimate(down: bool) -> None:
    # edge forces off: where the nominal chip is zero (up-milling entry, down-milling
    # exit) an eccentric flute starts its edge force late or early by |dr|/c, a kink that
    # is not linear in the eccentricity; the chip-proportional force is
    p = MillingParams(
        eccentricity=0.5e-6,
        eccentricity_deg=40.0,
        down_milling=down,
        radial_immersion=0.3,
        n_layers=6,
        k_te=0.0,
        k_re=0.0,
    )
    m = _stiff_machine(p)
    r = _last_rev(m, 4)
    ex, ey = _analytic_1x(p)
    gx = spindle_harmonic(r["fx"], r["psi"])
    gy = spindle_harmonic(r["fy"], r["psi"])
    assert abs(ex) > 0.1  # the estimate is not trivially zero
    assert abs(gx - ex) < 0.02 * abs(ex)
    assert abs(gy - ey) < 0.02 * max(abs(ey), abs(ex))


def test_force_scales_with_depth_and_has_the_right_mean_direction() -> None:
    r1 = _last_rev(MillingMachine(MillingParams(eccentricity=0.0)), 4)
    r2 = _last_rev(MillingMachine(MillingParams(eccentricity=0.0, axial_depth=2e-3)), 4)
    # twice the depth, about twice the force (drive compliance changes it a little)
    ratio = r2["fx"].mean() / r1["fx"].mean()
    assert 1.9 < ratio < 2.1
    # the workpiece is pushed along the feed (+x) on average in up-milling
    assert r1["fx"].mean() > 0


def test_drive_response_matches_simulated_circle() -> None:
    """The closed-loop G(jw) used for scoring is what the simulated axes do."""
    p = MillingParams(k_tc=0.0, k_rc=0.0, k_te=0.0, k_re=0.0, eccentricity=0.0)
    m = MillingMachine(p)
    a = 10e-6
    r = _last_rev(m, 30, a_m=a, theta_m=0.3)
    gx, gy = FeedDrives().response(p.spindle_hz)
    # carriage x phasor, the feed ramp removed
    xd = r["x"] - (r["rx"] - a * np.cos(r["psi"] + 0.3))
    ux = spindle_harmonic(xd, r["psi"])
    uy = spindle_harmonic(r["y"], r["psi"])
    cmd = a * np.exp(1j * 0.3)
    assert abs(ux - gx * cmd) < 1e-3 * a
    # y = a sin(psi + th) = Re(-j a e^{j th} e^{j psi})
    assert abs(uy - gy * (-1j) * cmd) < 1e-3 * a


def test_modulation_cancels_eccentricity_through_the_drives() -> None:
    p = MillingParams()
    m = MillingMachine(p)
    r0 = _last_rev(m, 6)
    j0 = abs(spindle_harmonic(r0["fx"], r0["psi"]))
    a, th = m.cancelling_modulation()
    r = _last_rev(m, 12, a_m=a, theta_m=th)
    j1 = abs(spindle_harmonic(r["fx"], r["psi"]))
    assert j0 > 5.0
    assert j1 < 0.02 * j0


def test_modulation_is_clamped_and_reported() -> None:
    m = MillingMachine(MillingParams(), max_modulation=30e-6)
    rec = m.step(100, a_m=50e-6, theta_m=0.0)
    assert rec.saturated and rec.a_m == pytest.approx(30e-6)
    rec = m.step(100, a_m=-50e-6, theta_m=0.0)
    assert rec.saturated and rec.a_m == pytest.approx(-30e-6)
    rec = m.step(100, a_m=10e-6, theta_m=0.0)
    assert not rec.saturated


@settings(max_examples=15, deadline=None)
@given(ri=st.floats(0.05, 1.0), down=st.booleans())
def test_engagement_window_matches_immersion(ri: float, down: bool) -> None:
    p = MillingParams(radial_immersion=ri, down_milling=down)
    a, b = p.engagement()
    # the swept width D/2 (cos(a) - cos(b)) over D equals the radial immersion
    assert 0.5 * (math.cos(a) - math.cos(b)) == pytest.approx(ri, abs=1e-12)


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        ({"radial_immersion": 0.0}, "radial_immersion"),
        ({"radial_immersion": 1.2}, "radial_immersion"),
        ({"radial_immersion": float("nan")}, "radial_immersion"),
        ({"n_flutes": 0}, "n_flutes"),
        ({"n_flutes": 2.5}, "n_flutes"),
        ({"diameter": 0.0}, "diameter"),
        ({"diameter": -1e-3}, "diameter"),
        ({"axial_depth": 0.0}, "axial_depth"),
        ({"spindle_rpm": 0.0}, "spindle_rpm"),
        ({"spindle_rpm": -1200.0}, "spindle_rpm"),
        ({"feed_per_tooth": 0.0}, "feed_per_tooth"),
        ({"eccentricity": -1e-6}, "eccentricity"),
        ({"helix_deg": 75.0}, "helix_deg"),
        ({"n_layers": 0}, "n_layers"),
    ],
)
def test_bad_milling_parameters_are_named(kw: dict[str, float], match: str) -> None:
    with pytest.raises(ParameterError, match=match):
        MillingParams(**kw)  # type: ignore[arg-type]


def test_bad_machine_inputs_are_named() -> None:
    m = MillingMachine(MillingParams())
    with pytest.raises(ParameterError, match="spindle_rpm"):
        m.set_spindle_rpm(0.0)
    with pytest.raises(ParameterError, match="'n'"):
        m.step(-1)
    with pytest.raises(ParameterError, match="a_m/theta_m"):
        m.step(10, a_m=float("nan"))
    with pytest.raises(ParameterError, match="max_modulation"):
        MillingMachine(MillingParams(), max_modulation=0.0)
    with pytest.raises(ParameterError, match="mass"):
        AxisParams(mass=0.0)
    with pytest.raises(ParameterError, match="sample_time"):
        FeedDriveParams(sample_time=0.01)


def test_a_flute_is_skipped_only_when_every_layer_is_outside_the_window() -> None:
    # the kernel skips a flute's layers when _flute_idle says all lie outside the
    # engagement window: each would add exact zeros, so the force is the same bits
    from machine.milling import _flute_idle

    rng = np.random.default_rng(3)
    two_pi = 2.0 * math.pi
    skipped = 0
    for _ in range(20000):
        down = bool(rng.integers(2))
        r = float(rng.uniform(0.02, 1.0))
        st, ex = (math.acos(2 * r - 1), math.pi) if down else (0.0, math.acos(1 - 2 * r))
        lags = np.sort(rng.uniform(0.0, 0.6, int(rng.integers(1, 12))))
        base = float(rng.uniform(-8.0, two_pi))
        if not _flute_idle(base, float(lags.max()), st, ex):
            continue
        skipped += 1
        for lag in lags:
            phi = base - lag  # as the kernel computes it
            while phi < 0.0:
                phi += two_pi
            p = phi % two_pi if phi >= two_pi else phi
            assert p < st or p > ex, (base, lag, st, ex)
    assert skipped > 5000  # the skip is taken (it is what makes the kernel faster)
