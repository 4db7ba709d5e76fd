"""The chatter reproduction's time-domain section: the simulator against the SD lobes.

A grid of spindle speeds and depths from 0.5x to 2x the SD boundary at each speed; each
point one simulated cut from rest (:func:`machine.chatter.growth_over`, the growth of
the non-forced vibration over 50 revolutions) and one SD verdict at the same point (its
critical multiplier inside the unit circle or not: an unstable island above the lowest
boundary is judged as such). The points within 10 % of the boundary are reported apart.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from common.modes import BENCHMARK_1DOF
from estimators.chatter.lobes import intervals_for, sd_boundary
from estimators.chatter.sd import SemiDiscretization
from machine.chatter import ChatterCutParams, Growth, growth_over
from server.experiments.reproduction import Check, Row, Section
from server.experiments.reproductions._chatter_lobes import (
    IMMERSIONS,
    SPEED_RANGE,
    benchmark_cut,
    tag,
)

#: depth over the SD boundary at each grid speed
RATIOS = (0.5, 0.6, 0.75, 0.9, 0.95, 1.05, 1.1, 1.25, 1.5, 2.0)
QUICK_RATIOS = (0.5, 0.75, 0.95, 1.05, 1.5, 2.0)
#: half-width of the band around the boundary reported apart
NEAR = 0.1
#: the issue's target: stable/unstable agreement away from the boundary
AGREEMENT = 0.95


@dataclass(frozen=True)
class GridPoint:
    """One simulated cut beside the SD verdict at the same speed and depth."""

    immersion: float
    rpm: float
    ratio: float
    depth: float
    sd_stable: bool
    sd_kind: str
    sd_freq_hz: float
    sim: Growth

    @property
    def agrees(self) -> bool:
        return self.sd_stable == self.sim.stable

    @property
    def near(self) -> bool:
        return abs(self.ratio - 1.0) <= NEAR + 1e-9


def speeds(quick: bool) -> np.ndarray:
    """The grid's speeds: 20 (quick: 4) spread over the benchmark's range, off the chart's
    own grid."""
    n = 4 if quick else 20
    lo, hi = SPEED_RANGE
    step = (hi - lo) / n
    return np.asarray(lo + step * (np.arange(n) + 0.5))


def grid(quick: bool, tick: Callable[[], None] | None = None) -> list[GridPoint]:
    """Every grid point of both immersions."""
    out = []
    for imm in IMMERSIONS:
        cut = benchmark_cut(imm)
        for rpm in speeds(quick):
            sd = SemiDiscretization(BENCHMARK_1DOF, cut, intervals_for(BENCHMARK_1DOF, cut, rpm))
            b = sd_boundary(sd, float(rpm)).depth
            for r in QUICK_RATIOS if quick else RATIOS:
                d = r * b
                mult = sd.multiplier(float(rpm), d)
                sim = growth_over(ChatterCutParams(BENCHMARK_1DOF, cut, d, float(rpm)))
                f = sd.chatter_frequency(float(rpm), d)
                out.append(GridPoint(imm, float(rpm), r, d, mult.modulus < 1.0, mult.kind, f, sim))
                if tick is not None:
                    tick()
    return out


def _rate(points: list[GridPoint]) -> float:
    return float(np.mean([p.agrees for p in points])) if points else float("nan")


def grid_section(points: list[GridPoint]) -> Section:
    """Agreement away from and near the boundary, each disagreement, frequencies."""
    rows: list[Row] = []
    checks: list[Check] = []
    for imm in (*IMMERSIONS, None):
        sel = [p for p in points if imm is None or p.immersion == imm]
        name = "all" if imm is None else tag(imm)
        far = [p for p in sel if not p.near]
        near = [p for p in sel if p.near]
        cond = f"{len({p.rpm for p in sel})} speeds x depths {sorted({p.ratio for p in sel})}"
        first = float(np.mean([p.sd_stable == p.sim.stable_as_first_defined for p in far]))
        rows += [
            Row(
                f"grid.{name}.agreement_far",
                _rate(far) * 100,
                None,
                "%",
                f"{len(far)} points beyond +-10 % of the SD boundary; {cond}",
            ),
            Row(
                f"grid.{name}.agreement_far_first_criterion",
                first * 100,
                None,
                "%",
                "the criterion as first defined (grew at all, or developed)",
            ),
            Row(
                f"grid.{name}.agreement_near",
                _rate(near) * 100,
                None,
                "%",
                f"{len(near)} points within +-10 % of the SD boundary",
            ),
        ]
        checks.append(
            Check(
                f"lobe.simulator_agreement_far.{name}",
                _rate(far) >= AGREEMENT,
                _rate(far) * 100,
                AGREEMENT * 100,
            )
        )
    for p in points:
        if not p.agrees:
            rows.append(
                Row(
                    f"grid.{tag(p.immersion)}.{p.rpm:.0f}rpm.x{p.ratio:g}.growth",
                    p.sim.growth,
                    None,
                    "-",
                    f"disagrees: SD {'stable' if p.sd_stable else 'unstable'} "
                    f"({p.sd_kind}), simulator {'stable' if p.sim.stable else 'unstable'}; "
                    f"non-forced/forced {p.sim.amp_nonforced / p.sim.amp_forced:.3f}, "
                    f"out of the cut {p.sim.out_of_cut:.0%} of the window",
                )
            )
    rows += _frequency_rows(points)
    return rows, checks


def _frequency_rows(points: list[GridPoint]) -> list[Row]:
    """Simulated chatter frequency against SD's, just above the boundary (1.05-1.25x)."""
    sel = [p for p in points if 1.0 < p.ratio <= 1.25 and not p.sd_stable and not p.sim.stable]
    if not sel:
        return []
    diff = [abs(p.sim.frequency_hz - p.sd_freq_hz) for p in sel]
    return [
        Row(
            "grid.chatter_freq.median_abs_diff_hz",
            float(np.median(diff)),
            None,
            "Hz",
            f"{len(sel)} unstable points at 1.05-1.25x; simulator's largest peak vs SD's",
        ),
        Row(
            "grid.chatter_freq.max_abs_diff_hz",
            float(np.max(diff)),
            None,
            "Hz",
            "the largest peak can be a tooth-harmonic sideband of SD's member",
        ),
    ]


__all__ = ["NEAR", "RATIOS", "GridPoint", "grid", "grid_section", "speeds"]
