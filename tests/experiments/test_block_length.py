"""What a worker's longer blocks cost the estimates: nothing. A measured log through the
live pipeline in blocks of 50 ms (the dashboard's 20 Hz), 100 ms (the worker's 10 Hz) and
400 ms (a worker catching up) gives bit-identical estimates at every sample: the
observers and identifiers run sample by sample and carry their state across blocks.
(A longer block only delays the estimate behind a drive block, by up to the block.)"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from server.experiments.residual_logs import simulate_stage, stage_case
from server.pipeline.live_pipeline import LivePipeline
from server.records.measured_log import write_log

CHANNELS = ("f_adaptive", "f_switching", "f_segment", "J_L_adaptive", "J_L_seg", "F_CL_seg",
            "f_dfo", "h1_amp")  # fmt: skip


def _run(log: Path, block: int) -> dict[str, np.ndarray]:
    p = LivePipeline.from_log(log)
    parts: dict[str, list[np.ndarray]] = {k: [] for k in (*CHANNELS, "t")}
    while True:
        out = p.step(block)
        if len(out["t"]) == 0:
            return {k: np.concatenate(v) for k, v in parts.items()}
        for k in parts:
            parts[k].append(out[k])


def test_the_estimates_do_not_depend_on_the_block_length(tmp_path: Path) -> None:
    cols, sidecar, _ = simulate_stage(stage_case([], 0), 12.0, seed=0)
    log = tmp_path / "run.csv"
    write_log(log, cols, sidecar)
    ref = _run(log, 125)
    assert len(ref["t"]) == len(cols["t"]) and np.isfinite(ref["f_adaptive"]).mean() > 0.99
    for block in (250, 1000):
        got = _run(log, block)
        for k in ref:
            assert np.array_equal(ref[k], got[k], equal_nan=True), (block, k)
