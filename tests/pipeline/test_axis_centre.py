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
