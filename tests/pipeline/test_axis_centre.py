"""Issue 31 item 2: the axes' process force on the machining centre's 500 Hz trace.

The live pipeline of scenario ``machining-centre`` over several seeds (each seed draws the
noise, the overrides, the depths, the tool lives and runouts), its ``axes`` part's
process force ``<axis>.F`` against the simulator's truth (the cycle's mean force on the
workpiece along the axis). Before the standstill friction of
:mod:`estimators.rigid_id` (the force's Coulomb column 0 at rest) the error was about
the force itself (6 seeds x 120 s: X 89 N of a 107 N force, Y 132 N of 119 N, Z 113 N of
22 N); the error's square sat 92-99 % where the axis stood.
"""

from __future__ import annotations

import numpy as np
import pytest

from server.pipeline.centre_source import CentreSource
from server.pipeline.live_pipeline import LivePipeline
from server.pipeline.sources import SourceBlock

pytestmark = pytest.mark.slow

SEEDS = (0, 4, 7)
SECONDS = 60.0
#: scored after the first part's moves have identified the axes
FROM_S = 20.0
RATE = 500.0


def _run(seed: int) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """The pipeline's axes channels, and beside them the simulator's truth and the trace's
    encoder positions (what the source handed the pipeline, recorded on the way)."""
    p = LivePipeline("machining-centre", seed=seed)
    src = p.source
    assert isinstance(src, CentreSource)
    seen: list[dict[str, np.ndarray]] = []
    step = src.step

    def recording(n: int) -> SourceBlock:
        blk = step(n)
        seen.append({k: blk.columns[k] for k in ("X_q_m", "Y_q_m", "Z_q_m")})
        seen[-1].update(src.truth)
        return blk

    src.step = recording  # type: ignore[method-assign]
    n = 25
    outs = [p.step(n) for _ in range(int(SECONDS * RATE / n))]
    out = {k: np.concatenate([o[k] for o in outs]) for k in outs[0] if k[:2] in ("X.", "Y.", "Z.")}
    rec = {k: np.concatenate([o[k] for o in seen]) for k in seen[0]}
    assert len(rec["X_q_m"]) == len(out["X.F"])
    return out, rec


@pytest.fixture(scope="module")
def runs() -> dict[int, tuple[dict[str, np.ndarray], dict[str, np.ndarray]]]:
    return {s: _run(s) for s in SEEDS}


def _scored(out: dict[str, np.ndarray], tru: dict[str, np.ndarray], axis: str):
    f, t = out[f"{axis}.F"], tru[f"true_{axis}_f_process"]
    sel = np.arange(len(f)) >= FROM_S * RATE
    assert np.isfinite(f[sel]).all(), axis
    return f[sel], t[sel], out[f"{axis}.F_sd"][sel]


def test_the_axes_process_force_error_is_well_below_the_force(runs: dict) -> None:
    """Every seed: X's and Y's rms error under half their force's rms (before: 0.83 and
    1.11), Z's (a 22 N force on a 3.9 kN weight) under 60 N (before: 113 N)."""
    rows = []
    for seed, (out, tru) in runs.items():
        for axis in "XYZ":
            f, t, _ = _scored(out, tru, axis)
            err, rms = float(np.sqrt(np.mean((f - t) ** 2))), float(np.sqrt(np.mean(t**2)))
            rows.append((seed, axis, err, rms))
    for _seed, axis, err, rms in rows:
        if axis == "Z":
            assert err < 60.0, rows
        else:
            assert err < 0.5 * rms, rows


def test_an_axis_at_rest_carries_the_cut_s_force_not_a_random_friction(runs: dict) -> None:
    """Where an axis stands (its encoder within 50 um for 0.4 s around the sample) and
    another cuts, the force on it is what its drive holds: the error there is under 0.3
    of the force (measured 0.26-0.27; before, 0.53-0.54: the Coulomb level's sign,
    +-270 to +-420 N, where the encoder dithers and creeps)."""
    for seed, (out, tru) in runs.items():
        for axis in "XY":
            f, t, _ = _scored(out, tru, axis)
            pos = tru[f"{axis}_q_m"][-len(f) :]
            w = int(0.2 * RATE)
            span = np.array([np.ptp(pos[max(0, i - w) : i + w]) for i in range(0, len(pos), 10)])
            still = np.repeat(span < 50e-6, 10)[: len(f)]
            cut = np.abs(t) > 20.0
            m = still & cut
            assert m.sum() > 0.05 * len(f), (seed, axis, int(m.sum()))
            err = float(np.sqrt(np.mean((f[m] - t[m]) ** 2)))
            force = float(np.sqrt(np.mean(t[m] ** 2)))
            assert err < 0.3 * force, (seed, axis, err, force)


def test_the_force_uncertainty_covers_the_error(runs: dict) -> None:
    """|F - truth| <= 2 F_sd on at least 95 % of the samples of every axis and seed
    (measured 0.991-0.999; before, 0.81-0.91: at rest the static friction's spread,
    Fc / sqrt 3, is in F_sd; on this simulation, whose friction at rest is ~0, that is
    conservative)."""
    cover = {}
    for seed, (out, tru) in runs.items():
        for axis in "XYZ":
            f, t, sd = _scored(out, tru, axis)
            cover[(seed, axis)] = float(np.mean(np.abs(f - t) <= 2.0 * sd))
    assert min(cover.values()) >= 0.95, cover


def test_seed_000_s_observer_on_x_from_the_parameters_identified_on_the_trace(runs: dict) -> None:
    """The two-inertia part identifies X's drive train from its trace (truth: K 170 N/um,
    M_M 1013 kg, M_L 341 kg with the blank, the mode 130 Hz) and its process force, the
    twist less the load's model, beats the rigid model's on every seed: the scale sees
    the load, so the motor side's 1013 kg (three quarters of the mass, whose
    acceleration steps the 500 Hz sampling blurs) is out of the force."""
    from machine.centre.params import CentreParams

    x = CentreParams().axes[0]
    for seed, (out, tru) in runs.items():
        last = {k: float(out[f"X.{k}"][-1]) for k in ("K", "M_M", "M_L", "mode_hz")}
        assert last["K"] == pytest.approx(x.stiffness, rel=0.03), (seed, last)
        assert last["M_M"] == pytest.approx(x.motor_mass, rel=0.03), (seed, last)
        assert last["M_L"] == pytest.approx(x.load(0.65), rel=0.05), (seed, last)
        assert last["mode_hz"] == pytest.approx(130.0, rel=0.03), (seed, last)
        f2, t, sd = _scored({"X.F": out["X.F_2i"], "X.F_sd": out["X.F_2i_sd"]}, tru, "X")
        f1, _, _ = _scored(out, tru, "X")
        e2 = float(np.sqrt(np.mean((f2 - t) ** 2)))
        e1 = float(np.sqrt(np.mean((f1 - t) ** 2)))
        assert e2 < 0.85 * e1, (seed, e2, e1)
        assert np.mean(np.abs(f2 - t) <= 2.0 * sd) >= 0.95, seed


def test_which_axes_the_parts_watch_and_where_they_cannot_run() -> None:
    """The monitor takes the axes whose force is in N (the centre's three; the cnc-mill
    export's currents in A without a force constant: none, so it is not built there);
    seed 000's observer the axes with a scale (X), and below 100 Hz it says why not."""
    import json
    from pathlib import Path

    from common.machine_description import from_dict
    from machine.centre import signals
    from server.pipeline.axis_monitor_part import monitored_axes
    from server.pipeline.two_inertia_part import TwoInertiaAxisPart, two_inertia_axes

    centre = signals.description(None, RATE)
    assert monitored_axes(centre) == ("X", "Y", "Z")
    assert two_inertia_axes(centre) == ("X",)
    mill = Path(__file__).resolve().parents[2] / "docs" / "machines" / "cnc-mill.json"
    assert monitored_axes(from_dict(json.loads(mill.read_text()))) == ()
    slow = TwoInertiaAxisPart(signals.description(None, 50.0))
    verdict = slow.requires(None)  # type: ignore[arg-type]  # refused before it looks
    assert not verdict.ok and "at 50 Hz" in verdict.reason and "100 Hz" in verdict.reason


@pytest.mark.slow
def test_a_collision_is_seen_on_the_axes_force_and_names_the_axis() -> None:
    """One part taught (teach_parts 1), a collision (3x the feed) injected into part 3's
    face cut (N60, T1, along X): the monitor on X's process force raises a collision
    naming X within 20 ms of the truth's first sample."""
    p = LivePipeline("machining-centre", seed=0)
    p.set_knob("teach_parts", 1)
    while p.t < 70.0:
        p.step(25)
    p.take_events()
    assert p.inject("collision")["line"] == 60
    events = []
    while p.t < 104.0:
        p.step(25)
        events += p.take_events()
    src = p.source
    assert isinstance(src, CentreSource)
    (truth,) = [e for e in src.events if e.kind == "collision"]
    seen = [
        e
        for e in events
        if e.kind == "collision" and "axis X" in e.message and 0 <= e.t - truth.t < 0.02
    ]
    assert seen, ([(e.t, e.kind, e.message[:60]) for e in events], truth.t)
    assert seen[0].line == 60 and seen[0].tool == 1 and seen[0].unit == "N"


def test_a_rate_change_keeps_the_two_inertia_parameters() -> None:
    """A new meta at another rate builds the part again: the motor side's and the load
    side's identified parameters are carried (in physical units), the filters restart,
    and the part says so."""
    from machine.centre import signals
    from server.pipeline.two_inertia_part import TwoInertiaAxisPart

    p = LivePipeline("machining-centre", seed=2)
    for _ in range(int(25.0 * RATE / 25)):
        p.step(25)
    old = p.part("two_inertia")
    assert isinstance(old, TwoInertiaAxisPart)
    k_old = float(old.st.motor["X"].theta[1])
    assert k_old == pytest.approx(170e6, rel=0.05)
    new = TwoInertiaAxisPart(signals.description(None, 1000.0))
    new.carry(old, p.t)
    assert float(new.st.motor["X"].theta[1]) == k_old and new.st.motor["X"].seen == 0
    np.testing.assert_array_equal(new.st.load["X"].theta, old.st.load["X"].theta)
    assert "for 1000 Hz (was 500 Hz)" in new.said and "X kept" in new.said
