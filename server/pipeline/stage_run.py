"""Wiring of the stage with its observers: source -> front end -> identifiers -> forces.

One :class:`StageRun` takes blocks from a measurement source (by default the simulated
stage; :mod:`server.pipeline.sources`) and runs, on their Measurements only, the
fixed-parameter observer (seed 000 Fig. 4), the adaptive observer (seed 000 Fig. 3,
ordinary RLS) and the switching-RLS observer (seed 001), and beside them the gated segment
identifier (:mod:`estimators.segment_id`: J_L, B_L, F_CL with 95 % intervals and
excitation flags). The Truth is used only to build the scoring signals (true force, the
ideal estimate Q(s) F_cut); a source without Truth gives its reference force ``f_ext``
instead (NaN when none).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from common.arrays import F64
from estimators.filters import lowpass
from estimators.force_observer import (
    LoadParams,
    ObserverParams,
    TorsionEstimator,
    TorsionState,
    cutting_force,
    cutting_force_lagged,
)
from estimators.force_observer import observer_design as rate_observer_design
from estimators.rls import IdentifierParams, IdentRecord, IdentState, LoadIdentifier
from estimators.segment_id import (
    SegmentIdentifier,
    SegmentIdentifierParams,
    SegmentRecord,
    SegmentState,
    mark_disturbance,
    restart,
)
from machine.stage import Measurements, StageConfig, StageSim, Truth
from machine.stage_params import StageParams
from server.errors import CutwatchError
from server.pipeline.sources import (
    RESUMED,
    MeasurementSource,
    SimulatorSource,
    SourceBlock,
    no_truth,
)

#: after a resume (:data:`RESUMED`), the RLS identifiers' estimates are held this long [s of
#: the feed] while the restarted filters settle (their transient is within 0.1 s)
RESUME_HOLD_S = 0.5


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
    f_segment: F64  # seed000 (2) with the gated segment identifier's parameters
    theta_adaptive: F64  # (n, 4) J_L, B_L, F_CL, F_DC
    theta_switching: F64
    mode_adaptive: NDArray[np.int8]
    mode_switching: NDArray[np.int8]
    alpha: F64
    excitation_index: float
    resets: int
    segment: SegmentRecord  # gated segment identifier: estimates, intervals, excited


@dataclass
class StageRunState:
    """Everything a :class:`StageRun` carries from block to block (checkpointed): the
    front end's, the identifiers' (RLS covariances included) and the segment
    identifier's states (its tracks), Q's state on the true force, and the last sample's
    parameters, force and time (the observers lag one sample)."""

    front: TorsionState
    ident: IdentState
    ident_switching: IdentState
    segment: SegmentState
    zq: F64
    theta_adaptive: F64
    theta_switching: F64
    theta_segment: F64
    prev_f: float
    prev_qf: float
    prev_t: float


def observer_params_for(cfg: StageConfig, **design: Any) -> ObserverParams:
    """The force observer's parameters for a simulated stage: its nominal (or true)
    parameters, its sample time and encoder, and ``design`` (e.g. ``q_hz``) on top."""
    return _observer_params(
        cfg.nominal or cfg.params, cfg.sample_time, cfg.encoder_resolution, **design
    )


def _observer_params(
    nom: StageParams, sample_time: float, encoder_resolution: float, **design: Any
) -> ObserverParams:
    return ObserverParams(
        J_M=nom.J_M,
        B_M=nom.B_M,
        F_CM=nom.F_CM,
        K=nom.K,
        sample_time=sample_time,
        encoder_resolution=encoder_resolution,
        **design,
    )


class StageRun:
    """A measurement source and every force observer, advanced together.

    Parameters
    ----------
    config, seed
        The simulated stage's configuration and seed, when ``source`` is not given.
    ident, observer_design
        The identifiers' parameters and the observer's design options.
    source
        Where the measurements come from (:mod:`server.pipeline.sources`); default a
        :class:`~server.pipeline.sources.SimulatorSource` of ``config`` and ``seed``.
        The observers are built from its nominal parameters and sample time.
    """

    def __init__(
        self,
        config: StageConfig | None = None,
        *,
        seed: int = 0,
        ident: IdentifierParams | None = None,
        observer_design: Mapping[str, float | str] | None = None,
        source: MeasurementSource | None = None,
    ) -> None:
        self.source: MeasurementSource = source or SimulatorSource(config, seed=seed)
        src = self.source
        nom = src.nominal
        self.nominal_load = LoadParams(J_L=nom.J_L, B_L=nom.B_L, F_CL=nom.F_CL)
        # designed from the rate (Q's cut-off; the load-side relation when the torsion
        # lies above the Nyquist frequency), a scenario's design on top
        rate_design, self.design_note = rate_observer_design(
            nom.J_M, nom.J_L, nom.K, src.sample_time
        )
        self.front = TorsionEstimator(
            _observer_params(
                nom,
                src.sample_time,
                src.encoder_resolution,
                **{**rate_design, **(observer_design or {})},
            )
        )
        ip = ident or IdentifierParams(sample_time=src.sample_time)
        self.ident = LoadIdentifier(ip, switching=False)
        self.ident_sw = LoadIdentifier(ip, switching=True)
        self.ident_seg = SegmentIdentifier(
            SegmentIdentifierParams(
                nominal=(nom.J_L, nom.B_L, nom.F_CL),
                sample_time=src.sample_time,
                q_rls_hz=ip.q_rls_hz,
                q_rls_order=ip.q_rls_order,
                acc_threshold=ip.acc_threshold,
            )
        )
        self._q = lowpass(self.front.params.q_hz, src.sample_time, self.front.params.q_order)
        self.reset_estimators()

    @property
    def sim(self) -> StageSim:
        """The simulated stage, when the source is the simulator.

        Raises
        ------
        TypeError
            The source is not a :class:`~server.pipeline.sources.SimulatorSource`.
        """
        if not isinstance(self.source, SimulatorSource):
            raise TypeError(f"the {self.source.name} source has no simulated stage")
        return self.source.sim

    def reset_estimators(self) -> None:
        """Every observer and identifier back to its initial state (the source's nominal
        parameters), as if the next block were the first."""
        nl = self.nominal_load
        self.s_front = self.front.initial_state()
        self.s_ident = self.ident.initial_state(nl.J_L, nl.B_L, nl.F_CL)
        self.s_sw = self.ident_sw.initial_state(nl.J_L, nl.B_L, nl.F_CL)
        # the cut engages and every filter starts at t = 0 (a step inside the first
        # acceleration segment, the start from rest): that segment is discarded
        self.s_seg = mark_disturbance(self.ident_seg.initial_state(), 0.0)
        self._zq = self._q.initial_state()
        self._theta_a = np.array([nl.J_L, nl.B_L, nl.F_CL, 0.0])
        self._theta_s = self._theta_a.copy()
        self._theta_g = self._theta_a[:3].copy()
        self._prev_f = 0.0
        self._prev_qf = 0.0
        self._prev_t = 0.0
        self._held: tuple[float, IdentState, IdentState] | None = None

    def state(self) -> StageRunState:
        """The estimators' state now (shares the arrays: copy it to keep it)."""
        return StageRunState(
            self.s_front,
            self.s_ident,
            self.s_sw,
            self.s_seg,
            self._zq,
            self._theta_a,
            self._theta_s,
            self._theta_g,
            self._prev_f,
            self._prev_qf,
            self._prev_t,
        )

    def restore(self, st: StageRunState) -> None:
        """Continue from ``st`` (of a run on the same source parameters)."""
        self.s_front, self.s_ident, self.s_sw, self.s_seg = (
            st.front,
            st.ident,
            st.ident_switching,
            st.segment,
        )
        self._zq = st.zq
        self._theta_a, self._theta_s, self._theta_g = (
            st.theta_adaptive,
            st.theta_switching,
            st.theta_segment,
        )
        self._prev_f, self._prev_qf, self._prev_t = st.prev_f, st.prev_qf, st.prev_t

    def step(self, n: int) -> StageBlock:
        """Take ``n`` samples from the source and run the observers on them.

        Raises
        ------
        CutwatchError
            The source had no sample (a live feed with nothing yet): use
            :meth:`process` on the source's blocks to handle that case.
        """
        block = self.source.step(n)
        if block.n == 0:
            raise CutwatchError(f"the {self.source.name} source gave no samples")
        return self.process(block)

    def process(self, block: SourceBlock) -> StageBlock:
        """Run the observers on one non-empty block; a block marked as a discontinuity
        first resets them (:meth:`reset_estimators`)."""
        meas = block.meas
        if block.discontinuity == RESUMED:
            self.restart_filters(float(meas.t[0]))
        elif block.discontinuity is not None:
            self.reset_estimators()
            # the filters start again inside whatever segment follows: discarded
            self.s_seg = mark_disturbance(self.s_seg, float(meas.t[0]))
        truth = block.truth if block.truth is not None else no_truth(meas)
        self.s_front, rec = self.front.step(self.s_front, meas.tau_m, meas.q_m, meas.q_l)
        self.s_ident, ra = self.ident.step(
            self.s_ident, rec.t_s, rec.acc_l, rec.vel_l, rec.sgn_l, rec.omega_l
        )
        # the excitation index streamed is the ordinary RLS's (StageBlock)
        self.s_sw, rs = self.ident_sw.step(
            self.s_sw, rec.t_s, rec.acc_l, rec.vel_l, rec.sgn_l, rec.omega_l, excitation=False
        )
        if self._held is not None:
            ra, rs = self._hold(float(meas.t[0]), ra, rs)
        t_est = np.concatenate([[self._prev_t], meas.t[:-1]])
        # the front end's outputs refer to the previous sample (one sample time back)
        self.s_seg, rg = self.ident_seg.step(
            self.s_seg,
            meas.t - self.source.sample_time,
            rec.t_s,
            rec.acc_l,
            rec.vel_l,
            rec.sgn_l,
        )
        nl = self.nominal_load
        f_fixed = cutting_force(rec, nl.J_L, nl.B_L, nl.F_CL)
        # the observer at sample k uses the parameters identified up to sample k-1
        f_ad = cutting_force_lagged(rec, self._theta_a, ra.theta)
        f_sw = cutting_force_lagged(rec, self._theta_s, rs.theta)
        self._theta_a = ra.theta[-1].copy()
        self._theta_s = rs.theta[-1].copy()
        f_seg = cutting_force_lagged(rec, self._theta_g, rg.theta)
        self._theta_g = rg.theta[-1].copy()
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

    def restart_filters(self, t: float) -> None:
        """The measurements resume after a break in a run that goes on (a restart from a
        checkpoint on a live feed, :data:`~server.pipeline.sources.RESUMED`): the filters
        on the measurements restart from rest, the estimates (parameters, covariances,
        the segment identifier's tracks) are kept; the segment around ``t`` is
        discarded."""
        nl = self.nominal_load
        fresh = self.ident.initial_state(nl.J_L, nl.B_L, nl.F_CL)
        self.s_front = self.front.initial_state()
        self.s_ident = replace(self.s_ident, zf=fresh.zf.copy())
        self.s_sw = replace(self.s_sw, zf=fresh.zf.copy())
        seg = self.ident_seg.initial_state()
        self.s_seg = mark_disturbance(replace(self.s_seg, zf=seg.zf, hist=seg.hist, seg=seg.seg), t)
        self._zq = self._q.initial_state()
        # the filters' start from rest is a transient (the positions step from 0 to where
        # the machine is): the RLS identifiers would take it for a huge acceleration and
        # drive J_L to its bound. Their estimates and covariances are held until it has
        # passed (only their regressor filters run).
        self._held = (t + RESUME_HOLD_S, self.s_ident, self.s_sw)

    def carry(self, old: StageRun, t: float) -> None:
        """Continue ``old``'s identification on this run, designed for another sample
        rate (a rate change mid-stream, the same machine): the identified J_L, B_L, F_CL
        of every identifier kept (the RLS estimates, covariances and window rows:
        :meth:`estimators.rls.LoadIdentifier.adopt`; the segment identifier's estimate,
        covariance and counts), every filter restarted (the front end, Q_RLS, Q) and the
        segment around ``t`` discarded; the RLS estimates held while the restarted
        filters settle, as after a resume (:meth:`restart_filters`)."""
        ts_old = old.source.sample_time
        self.s_front = self.front.initial_state()
        self.s_ident = self.ident.adopt(old.s_ident, ts_old)
        self.s_sw = self.ident_sw.adopt(old.s_sw, ts_old)
        seg = self.ident_seg.initial_state()
        self.s_seg = mark_disturbance(replace(old.s_seg, zf=seg.zf, hist=seg.hist, seg=seg.seg), t)
        self._zq = self._q.initial_state()
        self._theta_a = old._theta_a.copy()
        self._theta_s = old._theta_s.copy()
        self._theta_g = old._theta_g.copy()
        self._prev_f, self._prev_qf, self._prev_t = old._prev_f, 0.0, old._prev_t
        self._held = (t + RESUME_HOLD_S, self.s_ident, self.s_sw)

    def _hold(self, t0: float, ra: IdentRecord, rs: IdentRecord) -> tuple[IdentRecord, IdentRecord]:
        """Within :data:`RESUME_HOLD_S` of a resume: the identifiers' estimates and
        covariances as they were (the regressor filters' states go on); after: released."""
        assert self._held is not None
        until, si, ss = self._held
        if t0 >= until:
            self._held = None
            return ra, rs
        self.s_ident = replace(si, zf=self.s_ident.zf)
        self.s_sw = replace(ss, zf=self.s_sw.zf)
        ra = replace(ra, theta=np.broadcast_to(self._theta_a, ra.theta.shape).copy())
        rs = replace(rs, theta=np.broadcast_to(self._theta_s, rs.theta.shape).copy())
        return ra, rs

    def note_disturbance(self, t: float) -> None:
        """A known change of the cutting condition at ``t`` (spindle step, tool change):
        the segment identifier discards the reversal segment around it."""
        self.s_seg = mark_disturbance(self.s_seg, t)

    def note_restart(self, J_L: bool = False, B_L: bool = False, F_CL: bool = False) -> None:
        """A known change of load parameters (a fresh workpiece: J_L): they restart."""
        self.s_seg = restart(self.s_seg, (J_L, B_L, F_CL))
