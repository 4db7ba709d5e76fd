"""Every axis of a described machine identified live (two simulated rigid axes, one with
a torque, one with a current and its torque constant; a 10 Hz export with the CNC's
velocity and acceleration)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from common.machine_description import from_dict
from machine.rigid_axis import RigidAxisParams, simulate_rigid_axis
from server.pipeline.axis_identification import AxisIdentification

X = RigidAxisParams(M=120.0, Fv=300.0, Fc=25.0, offset=0.0, ripple=0.2, position_friction=0.0,
                    noise_rms=0.5)  # fmt: skip
Y = dataclasses.replace(X, M=60.0, Fv=150.0, Fc=12.0, offset=2.0)
MACHINE = {
    "sample_time": 1e-3,
    "axes": {
        "X": {"kind": "rigid", "signals": {"q_m": "X_q", "tau_m": "X_f"},
              "units": {"position": "m"}},
        "Y": {"kind": "rigid", "signals": {"q_m": "Y_q", "i_m": "Y_i"},
              "units": {"position": "m"}, "K_t": 40.0},
    },
}  # fmt: skip


def _columns(seconds: float) -> dict[str, np.ndarray]:
    x = simulate_rigid_axis(X, seconds, np.random.default_rng(1))
    y = simulate_rigid_axis(Y, seconds, np.random.default_rng(2))
    return {"t": x["t"], "X_q": x["q_m"], "X_f": x["tau_m"], "Y_q": y["q_m"],
            "Y_i": y["tau_m"] / 40.0}  # fmt: skip


def test_two_axes_are_identified_each_in_its_units() -> None:
    ai = AxisIdentification(from_dict(MACHINE))
    names = [c.name for c in ai.channels()]
    assert "X.M" in names and "Y.Fc_excited" in names and "Y.F_sd" in names
    units = {c.name: c.unit for c in ai.channels()}
    assert units["X.M"] == "N s^2/m" and units["Y.Fv"] == "N s/m"  # Y's current x K_t
    assert ai.reasons == {"X": {}, "Y": {}}
    cols = _columns(25.0)
    st = ai.initial_state()
    for a in range(0, len(cols["t"]), 50):
        st, out = ai.step(st, cols["t"][a : a + 50], {k: v[a : a + 50] for k, v in cols.items()})
    for ax, p in (("X", X), ("Y", Y)):
        assert out[f"{ax}.M"][-1] == pytest.approx(p.M, rel=0.02)
        assert out[f"{ax}.Fv"][-1] == pytest.approx(p.Fv, rel=0.05)
        assert out[f"{ax}.Fc"][-1] == pytest.approx(p.Fc, rel=0.05)
        assert out[f"{ax}.Fc_lo"][-1] < p.Fc < out[f"{ax}.Fc_hi"][-1]
        assert out[f"{ax}.M_excited"][-1] == 1.0
        assert np.sqrt(np.nanmean(out[f"{ax}.F"] ** 2)) < 2.0  # no process force here
    assert out["Y.Fc_pos"][-1] == pytest.approx(14.0, abs=0.7)  # Fc + offset


def test_at_10_hz_without_an_acceleration_the_mass_says_why() -> None:
    d = {**MACHINE, "sample_time": 0.1}
    ai = AxisIdentification(from_dict(d))
    assert "acceleration" in ai.reasons["X"]["M"]
    d["axes"] = {"X": {**MACHINE["axes"]["X"],
                       "signals": {"q_m": "X_q", "tau_m": "X_f", "qd_cmd": "X_vc",
                                   "qdd_cmd": "X_ac"}}}  # fmt: skip
    ai2 = AxisIdentification(from_dict(d))
    assert ai2.reasons == {"X": {}}  # the commanded velocity and acceleration stand in
    x = simulate_rigid_axis(X, 120.0, np.random.default_rng(3))
    sub = {"t": x["t"][::100], "X_q": x["q_m"][::100], "X_f": x["tau_m"][::100],
           "X_vc": x["qd"][::100], "X_ac": x["qdd"][::100]}  # fmt: skip
    st = ai2.initial_state()
    for a in range(0, len(sub["t"]), 5):
        st, out = ai2.step(st, sub["t"][a : a + 5], {k: v[a : a + 5] for k, v in sub.items()})
    assert out["X.Fc"][-1] == pytest.approx(X.Fc, rel=0.1)
    assert out["X.Fv"][-1] == pytest.approx(X.Fv, rel=0.1)
    assert not math.isnan(out["X.M"][-1])
