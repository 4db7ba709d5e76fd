"""Shared helpers of the stage reproductions (seed 000 and seed 001)."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, TypedDict

import numpy as np
from numpy.typing import NDArray
from tqdm import tqdm

from common.arrays import F64
from server.pipeline.stage_run import StageBlock, StageRun


@dataclass
class RunTrace:
    t: F64
    f_true: F64
    f_ideal: F64
    est: dict[str, F64]
    theta: dict[str, F64]  # (n, 4) per identifier
    mode_switching: NDArray[np.int8]
    resets: int


def run_stage(
    run: StageRun,
    seconds: float,
    *,
    block: int = 1250,
    progress: bool = False,
    label: str = "",
    events: Mapping[float, Callable[[StageRun], None]] | None = None,
) -> RunTrace:
    """Advance ``run`` for ``seconds``; ``events`` maps a time to an action applied just
    before the block starting at that time (times are rounded to the block grid)."""
    ts = run.sim.config.sample_time
    n_blocks = int(round(seconds / (block * ts)))
    pending = dict(sorted((events or {}).items()))
    blocks: list[StageBlock] = []
    for _ in tqdm(range(n_blocks), desc=label, disable=not progress, leave=False):
        for te in list(pending):
            if run.sim.t >= te - 0.5 * ts:
                pending.pop(te)(run)
        blocks.append(run.step(block))

    def cat(name: str) -> NDArray[Any]:
        return np.concatenate([getattr(b, name) for b in blocks])

    return RunTrace(
        t=cat("t_est"),
        f_true=cat("f_true"),
        f_ideal=cat("f_ideal"),
        est={
            "fixed": cat("f_fixed"),
            "adaptive": cat("f_adaptive"),
            "switching": cat("f_switching"),
        },
        theta={"adaptive": cat("theta_adaptive"), "switching": cat("theta_switching")},
        mode_switching=cat("mode_switching"),
        resets=blocks[-1].resets,
    )


def component(x: F64, t: F64, f_hz: float) -> float:
    """Amplitude of the component of ``x`` at ``f_hz`` (DC: the mean), over the whole
    periods contained in ``t``."""
    if f_hz == 0:
        return float(abs(np.mean(x)))
    ts = t[1] - t[0]
    n_per = int((t[-1] - t[0]) * f_hz)
    n = int(round(n_per / f_hz / ts))
    xx, tt = x[:n], t[:n]
    return float(2 * abs(np.mean(xx * np.exp(-2j * np.pi * f_hz * tt))))


def settle_time(t: F64, est: F64, truth: float, t0: float, tol: float = 0.1) -> float:
    """Seconds after ``t0`` until ``est`` stays within ``tol`` of ``truth`` (inf: never)."""
    m = t >= t0
    tt, ee = t[m], est[m]
    bad = np.abs(ee - truth) > tol * abs(truth)
    if not bad.any():
        return 0.0
    last = int(np.nonzero(bad)[0][-1])
    if last == len(tt) - 1:
        return float("inf")
    return float(tt[last + 1] - t0)


#: The two identifier variants every stage reproduction runs side by side.
#: "ours": the ridge follows the estimate (1/p0 = 10) — the project's design, used live.
#: "paper": the papers' recursion, the ridge fixed on the initial estimate with a weak
#: P_0 (p0 = 100); row names get the prefix ``paper_recursion.``.
class Variant(TypedDict):
    """An identifier variant: the :class:`IdentifierParams` fields it sets."""

    ridge: str
    p0: float


VARIANTS: dict[str, Variant] = {
    "ours": {"ridge": "previous", "p0": 0.1},
    "paper": {"ridge": "initial", "p0": 100.0},
}


def prefix(variant: str) -> str:
    return "" if variant == "ours" else "paper_recursion."
