"""What the drives see: the chain from the tool's vibration to a CNC's trace."""

from __future__ import annotations

import math

import numpy as np
import pytest

from common.errors import ParameterError
from common.modes import BENCHMARK_1DOF
from machine.feed_drives import AxisParams
from machine.signal_chain import (
    alias,
    attenuation_table,
    axis_force_response,
    db,
    housing_force_per_vibration,
    trace_average,
)
from machine.spindle import SpindleParams, torque_response


def test_a_2ms_mean_takes_about_22_db_off_922_hz_and_nulls_500_hz_multiples() -> None:
    assert db(trace_average(922.0, 2e-3)) == pytest.approx(-21.80, abs=0.01)
    for f in (500.0, 1000.0, 1500.0):
        assert trace_average(f, 2e-3) == 0.0
    assert trace_average(0.0, 2e-3) == 1.0


def test_where_frequencies_land() -> None:
    assert alias(922.0, 500.0) == pytest.approx(78.0)
    assert alias(922.0, 1000.0) == pytest.approx(78.0)
    assert alias(1250.0, 1000.0) == pytest.approx(250.0)
    assert alias(1000.0, 500.0) == pytest.approx(0.0)
    assert alias(260.0, 500.0) == pytest.approx(240.0)


def test_one_mode_passes_k_plus_i_w_c_per_unit_vibration() -> None:
    m = BENCHMARK_1DOF.modes[0]
    for f in (300.0, 922.0, 2000.0):
        w = 2 * math.pi * f
        c = 2 * m.damping * m.mass * m.omega
        assert housing_force_per_vibration(BENCHMARK_1DOF, f) == pytest.approx(
            abs(complex(m.stiffness, w * c)), rel=1e-9
        )


def test_the_axis_loop_passes_slow_forces_and_attenuates_fast_ones() -> None:
    ax = AxisParams()
    assert axis_force_response(ax, 2e-4, 0.5) == pytest.approx(1.0, abs=0.01)
    # far above the 18 Hz loop the derivative term dominates: kd / (m w) = 3 w_bw / w
    for f in (500.0, 1000.0):
        assert axis_force_response(ax, 2e-4, f) == pytest.approx(3 * 18.0 / f, rel=0.2)


def test_the_spindle_loop_passes_slow_torque_and_falls_as_2fbw_over_f() -> None:
    sp = SpindleParams()
    assert abs(torque_response(sp, 0.5)) == pytest.approx(1.0, abs=0.01)
    assert abs(torque_response(sp, 3000.0)) == pytest.approx(2 * 30.0 / 3000.0, rel=0.02)
    # the sampled loop tends to the continuous one as its sample time shrinks
    cont = torque_response(sp, 100.0)
    errs = [abs(torque_response(sp, 100.0, ts) / cont - 1) for ts in (2e-4, 2e-5, 2e-6)]
    assert errs[0] > errs[1] > errs[2] and errs[2] < 1e-3


def test_the_table_multiplies_its_stages() -> None:
    rows = attenuation_table(BENCHMARK_1DOF, AxisParams(), 2e-4, SpindleParams(), [250.0, 922.0])
    r = rows[1]
    gain = 10 ** (r.axis_servo_db / 20)
    assert r.axis_ma_per_um == pytest.approx(r.structure_n_per_um * gain / 60.0 * 1e3)
    assert r.trace500_ma_per_um == pytest.approx(r.axis_ma_per_um * 10 ** (r.average_2ms_db / 20))
    assert r.alias_500_hz == pytest.approx(78.0)
    assert rows[0].axis_servo_db > r.axis_servo_db  # the loop falls with frequency
    assert np.isfinite(r.spindle_servo_db)


def test_bad_inputs_are_named() -> None:
    with pytest.raises(ParameterError, match="axis"):
        housing_force_per_vibration(BENCHMARK_1DOF, 900.0, axis=2)
    with pytest.raises(ParameterError, match="rate_hz"):
        alias(900.0, 0.0)
    with pytest.raises(ParameterError, match="window_s"):
        trace_average(900.0, 0.0)
    with pytest.raises(ParameterError, match="freq_hz"):
        torque_response(SpindleParams(), -1.0)
    with pytest.raises(ParameterError, match="bandwidth_hz"):
        SpindleParams(bandwidth_hz=0.0)
