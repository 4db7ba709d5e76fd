"""The live pipeline's channels and their assembly from one block of every part.

:data:`CHANNELS` lists every per-sample output with unit, display group and label, in
the order the stream sends them; :func:`assemble` builds one block's arrays (float64,
contiguous, ``n`` values each, plus ``"t"``) from the observer bank's block, the
harmonic observer's record, the wear values, the eccentricity loop's and the process
monitor's channels (:mod:`server.pipeline.process_part`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from common.arrays import F64
from estimators.dfo import DfoRecord
from server.pipeline.eccentricity_part import ECC_CHANNELS
from server.pipeline.process_part import MON_CHANNELS
from server.pipeline.stage_run import StageBlock


@dataclass(frozen=True)
class Channel:
    name: str
    unit: str
    group: str
    label: str


CHANNELS: list[Channel] = [
    Channel("f_true", "N m", "force", "true cutting torque"),
    Channel("f_fixed", "N m", "force", "fixed-parameter observer"),
    Channel("f_adaptive", "N m", "force", "adaptive observer (RLS)"),
    Channel("f_switching", "N m", "force", "switching-RLS observer"),
    Channel("f_segment", "N m", "force", "observer on the gated segment identifier"),
    Channel("J_L_true", "kg m^2", "J_L", "true J_L"),
    Channel("J_L_adaptive", "kg m^2", "J_L", "J_L identified (RLS)"),
    Channel("J_L_switching", "kg m^2", "J_L", "J_L identified (switching RLS)"),
    Channel("B_L_true", "N m s/rad", "B_L", "true B_L"),
    Channel("B_L_adaptive", "N m s/rad", "B_L", "B_L identified (RLS)"),
    Channel("B_L_switching", "N m s/rad", "B_L", "B_L identified (switching RLS)"),
    Channel("F_CL_true", "N m", "F_CL", "true F_CL"),
    Channel("F_CL_adaptive", "N m", "F_CL", "F_CL identified (RLS)"),
    Channel("F_CL_switching", "N m", "F_CL", "F_CL identified (switching RLS)"),
    Channel("f_effects", "N m", "force", "fixed observer with the identified effects"),
    Channel("f_dfo", "N m", "force", "harmonic observer (DFO) on the segment observer"),
    Channel("h1_amp", "N m", "harmonics", "1st tooth-passing harmonic, DFO amplitude"),
    Channel("h2_amp", "N m", "harmonics", "2nd tooth-passing harmonic, DFO amplitude"),
    Channel("h1_true", "N m", "harmonics", "1st harmonic, true amplitude"),
    Channel("h2_true", "N m", "harmonics", "2nd harmonic, true amplitude"),
    Channel("vb_true", "mm", "wear", "flank wear, true"),
    Channel("vb_est", "mm", "wear", "flank wear, estimated from the adaptive observer"),
    Channel("vb_limit", "mm", "wear", "flank-wear limit (tool change)"),
    Channel("life_left", "min", "wear", "remaining tool life (wear clock)"),
    *(
        Channel(f"{q}_{suffix}", unit, q, f"{q} {what}")
        for q, unit in (("J_L", "kg m^2"), ("B_L", "N m s/rad"), ("F_CL", "N m"))
        for suffix, what in (
            ("seg", "identified (gated segments)"),
            ("lo", "95 % interval, lower bound"),
            ("hi", "95 % interval, upper bound"),
            ("excited", "excited (1) or not determined by the data (0)"),
        )
    ),
    Channel("mode_switching", "", "rls", "switching-RLS regressor mode"),
    Channel("excitation", "", "rls", "excitation index of the block"),
    Channel("omega_l", "rad/s", "motion", "load velocity (true)"),
    Channel("spindle_rpm", "rpm", "motion", "spindle speed in effect"),
    Channel("q_m", "rad", "motion", "motor angle (encoder)"),
    Channel("x_l", "m", "motion", "table position (load encoder x 10 mm lead)"),
] + [Channel(k, u, "eccentricity", lab) for k, (u, lab) in ECC_CHANNELS.items()]
# the process monitor (issue 21): NaN in a scenario without a part program
CHANNELS += [Channel(k, u, "monitor", lab) for k, (u, lab) in MON_CHANNELS.items()]
SCREW_LEAD = 0.01  # m per revolution, for the displayed table position (papers give none)
#: the force estimates scored by the accuracy panel: every force channel but the truth
FORCE_ESTIMATES = tuple(c.name for c in CHANNELS if c.group == "force" and c.name != "f_true")
#: channels a source without truth cannot know (the true harmonics and wear)
TRUTH_ONLY = (
    "h1_true",
    "h2_true",
    "vb_true",
    "vb_est",
    "vb_limit",
    "life_left",
    "mon_event_true",
)


@dataclass(frozen=True)
class BlockParts:
    """One block's results of every part of the pipeline, to be assembled."""

    b: StageBlock
    dfo: DfoRecord
    f_effects: F64
    true_amplitudes: F64  # true harmonic amplitudes (NaN: unknown)
    wear: Mapping[str, float]  # vb_true, vb_est, vb_limit, life_left
    spindle_rpm: float


def empty_block() -> dict[str, np.ndarray]:
    """The step of a source that gave no samples: every channel, none of them."""
    return {"t": np.zeros(0)} | {c.name: np.zeros(0) for c in CHANNELS}


def stage_channels(p: BlockParts, sample_time: float) -> dict[str, np.ndarray]:
    """Every channel but the eccentricity loop's, in :data:`CHANNELS` order."""
    b, dr, n = p.b, p.dfo, p.b.meas.t.size
    th_a, th_s, sg = b.theta_adaptive, b.theta_switching, b.segment
    return {
        # b.t_est, except that the very first estimate refers to t = -dt, not 0 twice
        "t": b.meas.t - sample_time,
        "f_true": b.f_true,
        "f_fixed": b.f_fixed,
        "f_adaptive": b.f_adaptive,
        "f_switching": b.f_switching,
        "f_segment": b.f_segment,
        "J_L_true": b.truth.J_L,
        "J_L_adaptive": th_a[:, 0],
        "J_L_switching": th_s[:, 0],
        "B_L_true": b.truth.B_L,
        "B_L_adaptive": th_a[:, 1],
        "B_L_switching": th_s[:, 1],
        "F_CL_true": b.truth.F_CL,
        "F_CL_adaptive": th_a[:, 2],
        "F_CL_switching": th_s[:, 2],
        "f_effects": p.f_effects,
        "f_dfo": dr.d_hat,
        "h1_amp": dr.amplitude[:, 0],
        "h2_amp": dr.amplitude[:, 1],
        "h1_true": np.full(n, p.true_amplitudes[0]),
        "h2_true": np.full(n, p.true_amplitudes[1]),
        **{k: np.full(n, p.wear[k]) for k in ("vb_true", "vb_est", "vb_limit", "life_left")},
        **{
            f"{q}_{suffix}": arr[:, j]
            for j, q in enumerate(("J_L", "B_L", "F_CL"))
            for suffix, arr in (
                ("seg", sg.theta),
                ("lo", sg.lower),
                ("hi", sg.upper),
                ("excited", sg.excited.astype(np.float64)),
            )
        },
        "mode_switching": b.mode_switching.astype(np.float64),
        "excitation": np.full(n, float(b.excitation_index)),
        "omega_l": b.truth.omega_l,
        "spindle_rpm": np.full(n, p.spindle_rpm),
        "q_m": b.meas.q_m,
        "x_l": b.meas.q_l * (SCREW_LEAD / (2 * math.pi)),
    }


def finish(out: dict[str, np.ndarray], *, has_truth: bool) -> dict[str, np.ndarray]:
    """Mask what a source without truth cannot know; every array float64, contiguous."""
    if not has_truth:
        n = out["t"].size
        for k in TRUTH_ONLY:
            out[k] = np.full(n, math.nan)
    return {k: np.ascontiguousarray(v, dtype=np.float64) for k, v in out.items()}


def no_eccentricity(n: int) -> dict[str, np.ndarray]:
    """The eccentricity channels of a scenario without the milling tool (NaN)."""
    return {k: np.full(n, math.nan) for k in ECC_CHANNELS}
