"""The centre's wear part in the live pipeline: built on the machining centre, the strip's
wear tiles of the spindle's tool from it, uncalibrated with an interval; a label with no
tool change is refused naming the field. Its accuracy over seeds is
``cutwatch reproduce centre-wear`` (docs/centre-wear.md)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from common.errors import ParameterError
from server.pipeline.centre_source import CentreSource
from server.pipeline.centre_wear_part import CentreWearPart, CentreWearPartState
from server.pipeline.live_pipeline import LivePipeline

#: four parts: three to teach every cut block, the fourth read
SECONDS = 130.0


@pytest.fixture(scope="module")
def run() -> tuple[LivePipeline, dict[str, np.ndarray], list[dict[str, object]]]:
    p = LivePipeline("machining-centre", seed=5)
    n = 250
    outs, status = [], []
    for _ in range(int(SECONDS / (n * p.sample_time))):
        outs.append(p.step(n))
        status.append(p.monitor_status())
    cat = {k: np.concatenate([o[k] for o in outs]) for k in outs[0] if k.startswith("tool_vb")}
    return p, cat, status


def _part(p: LivePipeline) -> CentreWearPart:
    return next(x for x in p._parts if isinstance(x, CentreWearPart))


def test_it_runs_on_the_centre_and_the_strip_shows_the_spindles_tool(run: tuple) -> None:
    p, out, status = run
    parts = {x["name"]: x for x in p.parts()}
    assert parts["centre_wear"]["running"], parts["centre_wear"]
    last = status[-1]
    assert last["wear_tool"] == last["tool"] > 0 and last["wear_of"] == ""
    assert last["wear_limit_mm"] == pytest.approx(0.3)
    assert last["wear_calibrated"] is False
    lo, mid, hi = last["wear_lo_share"], last["wear_share"], last["wear_hi_share"]
    assert 0.0 <= lo <= mid <= hi < 3.0
    assert math.isfinite(float(last["life_left_min"])) and last["life_left_min"] > 0
    # the estimate is streamed with its band and the limit; the band holds the estimate
    vb, vlo, vhi = out["tool_vb"], out["tool_vb_lo"], out["tool_vb_hi"]
    known = np.isfinite(vb)
    assert known[-1000:].all()
    assert np.all(vlo[known] <= vb[known]) and np.all(vb[known] <= vhi[known])
    assert np.all(out["tool_vb_limit"] == pytest.approx(0.3))
    # the simulator's flank wear of that tool (scoring only) is inside the 95 % band
    src = p.source
    assert isinstance(src, CentreSource)
    true_share = src._state.tools[int(last["wear_tool"])].vb() / 0.3e-3
    assert lo <= true_share <= hi


def test_each_cut_block_is_taught_per_tool_program_and_line(run: tuple) -> None:
    p, _, _ = run
    st = _part(p).st
    assert isinstance(st, CentreWearPartState)
    cut = {k for k, b in st.est.blocks.items() if b.n >= 3 and b.sum_w / b.n > 50.0}
    assert {k[0] for k in cut} == {1, 2, 3}
    assert all(k[1] == p.source.program for k in cut)  # type: ignore[attr-defined]


def test_a_label_without_a_tool_change_is_refused_naming_the_field(run: tuple) -> None:
    part = _part(run[0])
    with pytest.raises(ParameterError, match="tool"):
        part.label(2, 0.31)
    with pytest.raises(ParameterError, match="vb_mm"):
        part.label(2, -0.1)
    with pytest.raises(ParameterError, match="vb_mm"):
        part.label(2, 5.0)
