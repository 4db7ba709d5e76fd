"""Issue 13 items 2-3 over the live pipeline: the default scenario, shortened to 3
simulated minutes, several seeds (each draws spindle speed, feed, removal rate, wear rate
and current noise: server.experiments.reproductions.live_identifiability.knobs_for).

Scored every 10 ms after the first 30 s, per seed: the 95 % interval of each identified
parameter covers the truth >= 90 % of the time; J_L within 10 % >= 80 %, F_CL within
20 % >= 80 %, B_L within 30 % or flagged not excited >= 80 %; at every spindle step, tool
change and workpiece change no estimate leaves its previous interval by more than that
interval's width and the truth never lies further than one width outside the interval;
the DFO amplitudes are back within 5 % < 0.2 s after every spindle step.
"""

from __future__ import annotations

import numpy as np
import pytest

from server.experiments.reproductions.live_identifiability import (
    dfo_recovery,
    event_glitches,
    run_case,
    scores,
)

SEEDS = (0, 1, 2)
MINUTES = 3.0


@pytest.fixture(scope="module", params=SEEDS)
def run(request: pytest.FixtureRequest):
    tr = run_case(frozenset(), int(request.param), MINUTES)
    return tr, tr.arrays()


@pytest.mark.slow
def test_intervals_cover_the_truth(run) -> None:
    _, a = run
    sc = scores(a)
    for q in ("J_L", "B_L", "F_CL"):
        assert sc[f"segment.{q}.coverage"] >= 0.9, (q, sc[f"segment.{q}.coverage"])


@pytest.mark.slow
def test_point_estimates_within_their_bands(run) -> None:
    _, a = run
    sc = scores(a)
    assert sc["segment.J_L.within_10"] >= 0.8, sc["segment.J_L.within_10"]
    assert sc["segment.F_CL.within_20"] >= 0.8, sc["segment.F_CL.within_20"]
    assert sc["segment.B_L.within_or_unexcited"] >= 0.8, sc["segment.B_L.within_or_unexcited"]


@pytest.mark.slow
def test_no_glitch_at_changes(run) -> None:
    tr, a = run
    kinds = {k for k, _ in tr.events}
    assert "spindle" in kinds  # the 3 minutes hold spindle steps (every 15 s)
    g = event_glitches(a, tr.events)
    assert g, "no event scored"
    for k, v in g.items():
        assert v <= 1.0, (k, v)


@pytest.mark.slow
def test_dfo_back_within_5_percent_after_spindle_steps(run) -> None:
    tr, a = run
    rec = dfo_recovery(a["h"], tr.events, 4e-4)
    assert rec
    assert all(r < 0.2 for r in rec), rec


@pytest.mark.parametrize("scenario", ["default", "seed000-weight", "seed001-spindle"])
def test_scenario_switch_starts_from_the_prior_not_excited(scenario: str) -> None:
    # a scenario switch is a fresh pipeline: until its first reversal segment no
    # parameter claims to be known, and the prior interval holds the truth
    from server.pipeline.live_pipeline import LivePipeline

    p = LivePipeline(scenario)
    for _ in range(60):  # 3 s, before the first reversal (4 s)
        out = p.step(125)
        for q in ("J_L", "B_L", "F_CL"):
            assert not out[f"{q}_excited"].any()
            assert np.all(out[f"{q}_lo"] <= out[f"{q}_true"])
            assert np.all(out[f"{q}_true"] <= out[f"{q}_hi"])
