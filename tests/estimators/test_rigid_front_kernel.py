"""The rigid identifier's fused front end (:func:`estimators.rigid_id._front_kernel`, issue 32
item 3) gives the numbers the column-by-column path gives, bit for bit: a 500 Hz axis that
moves both ways, stands still, and has a NaN and an infinity in its effort, stepped in
50-sample blocks by both paths."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimators.rigid_id import RigidIdentifier, rigid_design


def _axis(n: int, ts: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t = np.arange(n) * ts
    v = 0.05 * np.sign(np.sin(2 * np.pi * 0.4 * t)) * (np.sin(2 * np.pi * 0.1 * t) > -0.5)
    q = np.cumsum(v) * ts  # moves both ways, stands still a third of the time
    rng = np.random.default_rng(7)
    tau = 30.0 * np.sign(v) + 200.0 * v + rng.normal(0.0, 0.5, n)
    tau[1234] = math.nan
    tau[2345] = math.inf
    return t, q, tau


@pytest.mark.parametrize("velocity_given", [False, True])
def test_fused_front_end_equals_the_column_path(
    monkeypatch: pytest.MonkeyPatch, velocity_given: bool
) -> None:
    ts = 1.0 / 500.0
    t, q, tau = _axis(6000, ts)
    qd = np.gradient(q, ts)
    params, _ = rigid_design(ts, velocity_given=velocity_given)
    ident = RigidIdentifier(params)
    runs = []
    for fused in (True, False):
        if not fused:
            monkeypatch.setattr(RigidIdentifier, "_fused", lambda *a: False)
        st = ident.initial_state()
        recs = []
        for k in range(0, len(t), 50):
            sl = slice(k, k + 50)
            kw = {"qd": qd[sl]} if velocity_given else {}
            st, rec = ident.step(st, t[sl], q[sl], tau[sl], **kw)
            recs.append(rec)
        runs.append((st, recs))
    (st_a, a), (st_b, b) = runs
    for name in ("force", "force_sd", "effort"):
        x = np.concatenate([getattr(r, name) for r in a])
        y = np.concatenate([getattr(r, name) for r in b])
        assert x.tobytes() == y.tobytes(), name
    assert (
        np.concatenate([r.theta for r in a]).tobytes()
        == np.concatenate([r.theta for r in b]).tobytes()
    )
    assert st_a.z.tobytes() == st_b.z.tobytes()
    assert st_a.G.tobytes() == st_b.G.tobytes()
    assert a[-1].reversals == b[-1].reversals > 2  # it moved both ways
    assert np.isfinite(a[-1].theta).all()  # and identified
