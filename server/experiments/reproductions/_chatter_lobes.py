"""The chatter reproduction's benchmark section: SD converged, ZOA beside it, published values.

Insperger & Stepan's 1-DOF milling benchmark (two flutes, Kt 6e8 N/m^2, Kn 2e8 N/m^2,
f_n 922 Hz, damping ratio 0.011, modal mass 0.03993 kg; down-milling at a/D = 1 and
0.05). Published lobe values: none found tabulated (searched the stored papers and pages
corpora for the benchmark's parameters and for tables of its critical depths, docs/chatter.md
lists the queries); the rows' ``paper`` column is empty and the reference is the converged
semi-discretization, itself checked against the ZOA (SD with the directional matrix
averaged must give the ZOA) and against the time-domain simulator (the grid section).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from common.arrays import F64
from common.cut_geometry import BENCHMARK_KN, BENCHMARK_KT, CutGeometry
from common.modes import BENCHMARK_1DOF
from estimators.chatter.lobes import LobeChart, converged_boundary, lobe_chart, sd_boundary
from estimators.chatter.sd import SemiDiscretization
from estimators.chatter.zoa import zoa_chart
from server.experiments.reproduction import Check, Row, Section

#: the benchmark's radial immersions (down-milling)
IMMERSIONS = (1.0, 0.05)
#: the speed range of the benchmark's charts [rpm]
SPEED_RANGE = (5000.0, 25000.0)
#: speeds the converged boundary is tabulated at [rpm]
TABLE_SPEEDS = (5000.0, 7500.0, 10000.0, 12500.0, 15000.0, 17500.0, 20000.0, 22500.0, 25000.0)
QUICK_TABLE_SPEEDS = (7500.0, 20000.0)
#: the issue's target for the ZOA at a/D = 1
ZOA_TOLERANCE = 0.05
#: the SD convergence criterion: relative change from m/2
SD_TOLERANCE = 0.005


def benchmark_cut(immersion: float) -> CutGeometry:
    """The benchmark's cut at radial immersion ``immersion`` (down-milling)."""
    return CutGeometry(2, immersion, True, BENCHMARK_KT, BENCHMARK_KN)


def tag(immersion: float) -> str:
    """Row-name tag of an immersion: ``ad1`` or ``ad0.05``."""
    return f"ad{immersion:g}"


def charts(quick: bool, tick: Callable[[], None] | None = None) -> dict[float, LobeChart]:
    """The lobe chart of each immersion over :data:`SPEED_RANGE`."""
    n = 41 if quick else 201
    rpms = np.linspace(*SPEED_RANGE, n)
    out = {}
    for imm in IMMERSIONS:
        out[imm] = lobe_chart(
            BENCHMARK_1DOF,
            benchmark_cut(imm),
            rpms,
            progress=(lambda i, total: tick()) if tick is not None else None,
        )
    return out


def converged_section(quick: bool) -> Section:
    """SD converged (m doubled from 100 until < 0.5 % change) beside the ZOA, per speed."""
    rows: list[Row] = []
    worst = 0.0
    speeds = QUICK_TABLE_SPEEDS if quick else TABLE_SPEEDS
    for imm in IMMERSIONS:
        cut = benchmark_cut(imm)
        zd, _ = zoa_chart(BENCHMARK_1DOF, cut, np.array(speeds))
        for rpm, z in zip(speeds, zd, strict=True):
            b, change = converged_boundary(BENCHMARK_1DOF, cut, rpm, tol=SD_TOLERANCE)
            worst = max(worst, change)
            cond = f"down-milling a/D={imm:g}, {rpm:.0f} rpm"
            pre = f"{tag(imm)}.{rpm:.0f}rpm"
            rows += [
                Row(
                    f"{pre}.sd_depth_mm",
                    b.depth * 1e3,
                    None,
                    "mm",
                    f"{cond}; SD m={b.intervals} ({b.kind}); no published table found",
                ),
                Row(f"{pre}.sd_change_from_half_m", change * 100, None, "%", cond),
                Row(f"{pre}.zoa_depth_mm", z * 1e3, None, "mm", cond),
                Row(f"{pre}.zoa_gap", (z / b.depth - 1.0) * 100, None, "%", f"{cond}; ZOA/SD-1"),
            ]
    checks = [Check("lobe.sd_converged_below_0.5pct", worst <= SD_TOLERANCE, worst * 100, 0.5)]
    return rows, checks


def averaged_check() -> Section:
    """SD with its directional matrix replaced by the mean must reproduce the ZOA: the two
    implementations (and their sign conventions) checked against each other."""
    worst = 0.0
    rows = []
    for imm in IMMERSIONS:
        cut = benchmark_cut(imm)
        sd = SemiDiscretization(BENCHMARK_1DOF, cut, 200, averaged=True)
        for rpm in (6000.0, 15000.0):
            z = zoa_chart(BENCHMARK_1DOF, cut, np.array([rpm]), n_freq=20000)[0][0]
            d = sd_boundary(sd, rpm).depth
            worst = max(worst, abs(d / z - 1.0))
    rows.append(Row("sd_averaged_vs_zoa", worst * 100, None, "%", "SD with A(t) averaged, m=200"))
    return rows, [Check("lobe.sd_averaged_equals_zoa", worst < 0.005, worst * 100, 0.5)]


def _minimum(depth: F64) -> float:
    return float(np.min(depth[np.isfinite(depth)]))


def chart_section(ch: dict[float, LobeChart]) -> Section:
    """The ZOA/SD gap over the chart; where the ZOA misses the flip lobes."""
    rows: list[Row] = []
    full = ch[1.0]
    gap = full.gap()
    cond = f"a/D=1, {full.rpm.size} speeds {SPEED_RANGE[0]:.0f}-{SPEED_RANGE[1]:.0f} rpm"
    min_gap = _minimum(full.zoa_depth) / _minimum(full.sd_depth) - 1.0
    hopf = np.array([k == "hopf" for k in full.sd_kind])
    rows += [
        Row("ad1.zoa_gap.max_abs", float(np.max(np.abs(gap))) * 100, None, "%", cond),
        Row("ad1.zoa_gap.median_abs", float(np.median(np.abs(gap))) * 100, None, "%", cond),
        Row(
            "ad1.zoa_gap.hopf_median_abs",
            float(np.median(np.abs(gap[hopf]))) * 100,
            None,
            "%",
            cond + ", where SD's boundary is Hopf",
        ),
        Row("ad1.zoa_gap.at_minimum", min_gap * 100, None, "%", cond + "; lowest depth of each"),
        Row("ad1.sd_min_depth_mm", _minimum(full.sd_depth) * 1e3, None, "mm", cond),
        Row("ad1.zoa_min_depth_mm", _minimum(full.zoa_depth) * 1e3, None, "mm", cond),
        Row("ad1.flip_fraction", float(np.mean(~hopf)) * 100, None, "%", cond + ", SD flip"),
    ]
    within = float(np.mean(np.abs(gap) <= ZOA_TOLERANCE)) * 100
    rows.append(Row("ad1.zoa_within_5pct_fraction", within, None, "%", cond))
    rows += flip_rows(ch[0.05])
    checks = [
        Check(
            "lobe.zoa_within_5pct_ad1",
            float(np.max(np.abs(gap))) <= ZOA_TOLERANCE,
            float(np.max(np.abs(gap))) * 100,
            ZOA_TOLERANCE * 100,
        ),
        Check(
            "lobe.zoa_minimum_within_5pct_ad1",
            abs(min_gap) <= ZOA_TOLERANCE,
            abs(min_gap) * 100,
            ZOA_TOLERANCE * 100,
        ),
    ]
    return rows, checks


def flip_rows(low: LobeChart) -> list[Row]:
    """At a/D = 0.05: the speed ranges of SD's flip lobes and the ZOA's overestimate there."""
    flip = np.array([k == "flip" for k in low.sd_kind])
    ratio = low.zoa_depth / low.sd_depth
    rows = [
        Row(
            "ad0.05.flip_fraction",
            float(np.mean(flip)) * 100,
            None,
            "%",
            f"a/D=0.05, {low.rpm.size} speeds; SD boundary is a flip lobe",
        )
    ]
    for i, (a, b) in enumerate(_runs(flip)):
        seg = slice(a, b)
        k = a + int(np.argmax(ratio[seg]))
        pre = f"ad0.05.flip_lobe{i + 1}"
        cond = f"SD flip from {low.rpm[a]:.0f} to {low.rpm[b - 1]:.0f} rpm"
        rows += [
            Row(f"{pre}.rpm_from", float(low.rpm[a]), None, "rpm", cond),
            Row(f"{pre}.rpm_to", float(low.rpm[b - 1]), None, "rpm", cond),
            Row(
                f"{pre}.zoa_over_sd.max",
                float(ratio[k]),
                None,
                "-",
                f"{cond}; at {low.rpm[k]:.0f} rpm SD {low.sd_depth[k] * 1e3:.2f} mm",
            ),
        ]
    hopf = ~flip & np.isfinite(ratio)
    rows.append(
        Row(
            "ad0.05.zoa_gap.hopf_median_abs",
            float(np.median(np.abs(ratio[hopf] - 1.0))) * 100,
            None,
            "%",
            "a/D=0.05 where SD's boundary is Hopf",
        )
    )
    return rows


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """``[start, stop)`` of each run of true values."""
    out = []
    i = 0
    n = mask.size
    while i < n:
        if mask[i]:
            j = i
            while j < n and mask[j]:
                j += 1
            out.append((i, j))
            i = j
        else:
            i += 1
    return out


__all__ = [
    "IMMERSIONS",
    "SPEED_RANGE",
    "averaged_check",
    "benchmark_cut",
    "chart_section",
    "charts",
    "converged_section",
    "tag",
]
