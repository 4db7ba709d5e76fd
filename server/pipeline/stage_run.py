"""Wiring of the stage with its observers: simulation -> front end -> identifiers -> forces.

One :class:`StageRun` advances the simulated stage block by block and runs, on its
Measurements only, the fixed-parameter observer (seed 000 Fig. 4), the adaptive observer
(seed 000 Fig. 3, ordinary RLS) and the switching-RLS observer (seed 001), and beside
them the gated segment identifier (:mod:`estimators.segment_id`: J_L, B_L, F_CL with 95 %
intervals and excitation flags). The Truth is used only to build the scoring signals
(true force, the ideal estimate Q(s) F_cut).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from common.arrays import F64
from estimators.filters import lowpass
from estimators.force_observer import LoadParams, ObserverParams, TorsionEstimator, cutting_force
from estimators.rls import IdentifierParams, LoadIdentifier
from estimators.segment_id import (
    SegmentIdentifier,
    SegmentIdentifierParams,
    SegmentRecord,
    mark_disturbance,
    restart,
)
from machine.stage import Measurements, StageConfig, StageSim, Truth


@dataclass
class StageBlock:
    """Everything one block produced (per-sample arrays)."""

    meas: Measurements
    truth: Truth
    t_est: F64  # time each estimate refers to (one sample behind, see force_observer)
    f_true: F64  # true force at t_est
    f_ideal: F64  # Q(s) applied to the true force, at t_est
    f_fixed: F64
    f_adaptive: F64
    f_switching: F64
    f_segment: F64  # eq. (2) with the gated segment identifier's parameters
    theta_adaptive: F64  # (n, 4) J_L, B_L, F_CL, F_DC
    theta_switching: F64
    mode_adaptive: NDArray[np.int8]
    mode_switching: NDArray[np.int8]
    alpha: F64
    excitation_index: float
    resets: int
    segment: SegmentRecord  # gated segment identifier: estimates, intervals, excited


def observer_params_for(cfg: StageConfig, **design: Any) -> ObserverParams:
    nom = cfg.nominal or cfg.params
    return ObserverParams(
        J_M=nom.J_M,
        B_M=nom.B_M,
        F_CM=nom.F_CM,
        K=nom.K,
        sample_time=cfg.sample_time,
        encoder_resolution=cfg.encoder_resolution,
        **design,
    )


class StageRun:
    """The stage and every force observer, advanced together."""

    def __init__(
        self,
        config: StageConfig | None = None,
        *,
        seed: int = 0,
        ident: IdentifierParams | None = None,
        observer_design: dict[str, Any] | None = None,
    ) -> None:
        self.sim = StageSim(config or StageConfig(), seed=seed)
        cfg = self.sim.config
        nom = cfg.nominal or cfg.params
        self.nominal_load = LoadParams(J_L=nom.J_L, B_L=nom.B_L, F_CL=nom.F_CL)
        self.front = TorsionEstimator(observer_params_for(cfg, **(observer_design or {})))
        ip = ident or IdentifierParams(sample_time=cfg.sample_time)
        self.ident = LoadIdentifier(ip, switching=False)
        self.ident_sw = LoadIdentifier(ip, switching=True)
        self.ident_seg = SegmentIdentifier(
            SegmentIdentifierParams(
                nominal=(nom.J_L, nom.B_L, nom.F_CL),
                sample_time=cfg.sample_time,
                q_rls_hz=ip.q_rls_hz,
                q_rls_order=ip.q_rls_order,
                acc_threshold=ip.acc_threshold,
            )
        )
        self._q = lowpass(self.front.params.q_hz, cfg.sample_time, self.front.params.q_order)
        self._reset_estimators()

    def _reset_estimators(self) -> None:
        nl = self.nominal_load
        self.s_front = self.front.init_state()
        self.s_ident = self.ident.init_state(nl.J_L, nl.B_L, nl.F_CL)
        self.s_sw = self.ident_sw.init_state(nl.J_L, nl.B_L, nl.F_CL)
        # the cut engages and every filter starts at t = 0 (a step inside the first
        # acceleration segment, the start from rest): that segment is discarded
        self.s_seg = mark_disturbance(self.ident_seg.init_state(), 0.0)
        self._zq = self._q.initial_state()
        self._theta_a = np.array([nl.J_L, nl.B_L, nl.F_CL, 0.0])
        self._theta_s = self._theta_a.copy()
        self._theta_g = self._theta_a[:3].copy()
        self._prev_f = 0.0
        self._prev_qf = 0.0
        self._prev_t = 0.0

    def step(self, n: int) -> StageBlock:
        meas, truth = self.sim.step(n)
        self.s_front, rec = self.front.step(self.s_front, meas.tau_m, meas.q_m, meas.q_l)
        self.s_ident, ra = self.ident.step(
            self.s_ident, rec.t_s, rec.acc_l, rec.vel_l, rec.sgn_l, rec.omega_l
        )
        self.s_sw, rs = self.ident_sw.step(
            self.s_sw, rec.t_s, rec.acc_l, rec.vel_l, rec.sgn_l, rec.omega_l
        )
        t_est = np.concatenate([[self._prev_t], meas.t[:-1]])
        self.s_seg, rg = self.ident_seg.step(
            self.s_seg, t_est, rec.t_s, rec.acc_l, rec.vel_l, rec.sgn_l
        )
        nl = self.nominal_load
        f_fixed = cutting_force(rec, nl.J_L, nl.B_L, nl.F_CL)
        # the observer at sample k uses the parameters identified up to sample k-1
        th_a = np.vstack([self._theta_a, ra.theta[:-1]])
        th_s = np.vstack([self._theta_s, rs.theta[:-1]])
        self._theta_a = ra.theta[-1].copy()
        self._theta_s = rs.theta[-1].copy()
        f_ad = cutting_force(rec, th_a[:, 0], th_a[:, 1], th_a[:, 2])
        f_sw = cutting_force(rec, th_s[:, 0], th_s[:, 1], th_s[:, 2])
        th_g = np.vstack([self._theta_g, rg.theta[:-1]])
        self._theta_g = rg.theta[-1].copy()
        f_seg = cutting_force(rec, th_g[:, 0], th_g[:, 1], th_g[:, 2])
        qf, self._zq = self._q.run(truth.f_cut, self._zq)
        # estimates refer to the previous sample: align truth one sample back
        f_true = np.concatenate([[self._prev_f], truth.f_cut[:-1]])
        f_ideal = np.concatenate([[self._prev_qf], qf[:-1]])
        self._prev_f = float(truth.f_cut[-1])
        self._prev_qf = float(qf[-1])
        self._prev_t = float(meas.t[-1])
        return StageBlock(
            meas=meas,
            truth=truth,
            t_est=t_est,
            f_true=f_true,
            f_ideal=f_ideal,
            f_fixed=f_fixed,
            f_adaptive=f_ad,
            f_switching=f_sw,
            f_segment=f_seg,
            theta_adaptive=ra.theta,
            theta_switching=rs.theta,
            mode_adaptive=ra.mode,
            mode_switching=rs.mode,
            alpha=rec.alpha,
            excitation_index=ra.excitation_index,
            resets=ra.resets + rs.resets,
            segment=rg,
        )

    def note_disturbance(self, t: float) -> None:
        """A known change of the cutting condition at ``t`` (spindle step, tool change):
        the segment identifier discards the reversal segment around it."""
        self.s_seg = mark_disturbance(self.s_seg, t)

    def note_restart(self, J_L: bool = False, B_L: bool = False, F_CL: bool = False) -> None:
        """A known change of load parameters (a fresh workpiece: J_L): they restart."""
        self.s_seg = restart(self.s_seg, (J_L, B_L, F_CL))
