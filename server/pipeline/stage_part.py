"""The stage observers as a live part: seed 000/001's force observers and the identifiers.

:class:`StagePart` runs :class:`~server.pipeline.stage_run.StageRun` on the source's
blocks: the fixed-parameter, adaptive (RLS) and switching-RLS force observers, the
observer on the gated segment identifier's parameters, and beside them the identified
load parameters (J_L, B_L, F_CL) with their 95 % intervals and excitation flags. Its
channels are declared here, with the charts they are drawn on; the stage's block goes to
the later parts under ``block.shared["stage"]`` (the harmonic observer, the identified
effects, the wear monitor read it).

What it needs: a two-inertia axis (motor current or torque, motor position, load
position: the shaft-twist branch of seed 000 (4) reads both) and a sample rate whose
Nyquist frequency lies above the force observer's Q(s) cut-off.

What the CNC knows (:class:`~server.pipeline.part.Notice`): a spindle step or a tool
change marks a disturbance (the segment identifier discards the reversal segment around
it); a fresh workpiece restarts J_L.

A change of the sample rate (a new meta) builds the part again for the new rate and
carries the identified J_L, B_L, F_CL over, the filters restarted
(:meth:`StagePart.carry`); its status says so.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from common.arrays import F64
from estimators.rls import IdentifierParams
from server.pipeline.machine_view import MachineView
from server.pipeline.part import (
    OK,
    Block,
    Channel,
    Chart,
    LivePart,
    Notice,
    Outputs,
    Verdict,
    needs_axis,
    needs_band,
    refuse,
)
from server.pipeline.sources import RESUMED, MeasurementSource
from server.pipeline.stage_run import StageBlock, StageRun, StageRunState

__all__ = ["COLORS", "FORCE", "SCREW_LEAD", "StagePart"]

#: the colours of the estimators, the same on every chart
COLORS = {
    "true": "#1d232b",
    "fixed": "#e69f00",
    "adaptive": "#0072b2",
    "switching": "#cc3311",
    "segment": "#7b3294",
    "dfo": "#009e73",
    "effects": "#56b4e9",
    "grey": "#888888",
}
SCREW_LEAD = 0.01  # m per revolution, for the displayed table position (papers give none)

#: the cutting force, true against every observer (the DFO's and the effects' too)
FORCE = Chart(
    "force",
    "Cutting force: true vs observers (drag to zoom, double-click to follow)",
    order=10,
    window_s=0.5,
    fast=True,
    wide=True,
    markers=True,
)
_PARAMS = {
    q: Chart(q, f"{q} identified vs true", order=20 + i)
    for i, q in enumerate(("J_L", "B_L", "F_CL"))
}
RLS = Chart("rls", "RLS mode and excitation", order=80)
_UNITS = {"J_L": "kg m^2", "B_L": "N m s/rad", "F_CL": "N m"}


def _param_channels(q: str) -> tuple[Channel, ...]:
    u, c = _UNITS[q], COLORS
    drawn = _PARAMS[q].series(
        Channel(f"{q}_true", u, f"true {q}", q, truth=True, color=c["true"], legend="true"),
        Channel(f"{q}_adaptive", u, f"{q} identified (RLS)", q, color=c["adaptive"], legend="RLS"),
        Channel(
            f"{q}_switching",
            u,
            f"{q} identified (switching RLS)",
            q,
            color=c["switching"],
            legend="switching RLS",
        ),
        Channel(
            f"{q}_seg",
            u,
            f"{q} identified (gated segments)",
            q,
            color=c["dfo"],
            width=2,
            interval=(f"{q}_lo", f"{q}_hi", f"{q}_excited"),
            legend="identified",
        ),
    )
    hidden = (
        Channel(f"{q}_lo", u, f"{q} 95 % interval, lower bound", q),
        Channel(f"{q}_hi", u, f"{q} 95 % interval, upper bound", q),
        Channel(f"{q}_excited", "", f"{q} excited (1) or not determined by the data (0)", q),
    )
    return drawn + hidden


_CHANNELS: tuple[Channel, ...] = (
    *FORCE.series(
        Channel(
            "f_true",
            "N m",
            "true cutting torque",
            "force",
            truth=True,
            color=COLORS["true"],
            role="reference",
            legend="true",
        ),
        Channel(
            "f_fixed",
            "N m",
            "fixed-parameter observer",
            "force",
            color=COLORS["fixed"],
            role="without_effects",
            legend="fixed",
        ),
        Channel(
            "f_adaptive",
            "N m",
            "adaptive observer (RLS)",
            "force",
            color=COLORS["adaptive"],
            legend="adaptive",
        ),
        Channel(
            "f_switching",
            "N m",
            "switching-RLS observer",
            "force",
            color=COLORS["switching"],
            legend="switching",
        ),
        Channel(
            "f_segment",
            "N m",
            "observer on the gated segment identifier",
            "force",
            color=COLORS["segment"],
            legend="segment identifier",
        ),
    ),
    *(ch for q in ("J_L", "B_L", "F_CL") for ch in _param_channels(q)),
    *RLS.series(
        Channel(
            "mode_switching",
            "",
            "switching-RLS regressor mode",
            "rls",
            color=COLORS["segment"],
            legend="mode",
        ),
        Channel(
            "excitation",
            "",
            "excitation index of the block",
            "rls",
            color=COLORS["dfo"],
            legend="excitation",
        ),
    ),
    Channel("omega_l", "rad/s", "load velocity (true)", "motion", truth=True),
    Channel("spindle_rpm", "rpm", "spindle speed in effect", "motion"),
    Channel("q_m", "rad", "motor angle (encoder)", "motion"),
    Channel("x_l", "m", "table position (load encoder x 10 mm lead)", "motion"),
)


class StagePart(LivePart):
    """The stage's force observers and identifiers (module docstring).

    Parameters
    ----------
    source
        The measurement source (its nominal parameters and sample time build the
        observers).
    ident, design
        The identifiers' parameters and the observer's design options.
    """

    name = "stage"
    charts = (FORCE, *_PARAMS.values(), RLS)
    channels = _CHANNELS

    def __init__(
        self, source: MeasurementSource, ident: IdentifierParams, design: dict[str, float]
    ) -> None:
        self.run = StageRun(source=source, ident=ident, observer_design=dict(design))
        #: what the part says beside running (a rate change it followed)
        self.said = ""
        self._carried = False

    def requires(self, machine: MachineView) -> Verdict:
        q_hz = self.run.front.params.q_hz
        return (
            needs_axis(
                machine, "q_m", "q_l", kind="two_inertia", what="seed 000's shaft-twist branch"
            )
            and _needs_prior(machine)
            and needs_band(machine, q_hz, "the force observer's Q(s) cut-off")
        )

    def carry(self, old: StagePart, t: float) -> None:
        """Take ``old``'s identified load parameters (a pipeline built again for a new
        meta): :meth:`~server.pipeline.stage_run.StageRun.carry`; a new rate is said in
        the status. Nothing is carried from a run that saw no sample (the pipeline built
        before the feed's first meta, on a placeholder) nor across a change of the
        nominal load parameters (another machine described: it starts on its nominal)."""
        if t <= 0.0 or old.run.nominal_load != self.run.nominal_load:
            return
        self.run.carry(old.run, t)
        self._carried = True  # the first block's break (the meta changed): restarted here
        ts0, ts1 = old.run.source.sample_time, self.run.source.sample_time
        if ts0 != ts1:
            self.said = (
                f"designed again at t = {t:.3f} s for {1 / ts1:g} Hz (was {1 / ts0:g} Hz): "
                "identified J_L, B_L, F_CL kept, filter states restarted"
            )

    def notice(self, change: Notice) -> None:
        if change.kind == "disturbance":
            self.run.note_disturbance(change.t)
        else:
            self.run.note_restart(*(p in change.params for p in ("J_L", "B_L", "F_CL")))

    def step(self, block: Block) -> Outputs:
        src = block.source
        if self._carried:  # carried over (carry restarted the filters): the estimates go on
            self._carried = False
            src = dataclasses.replace(src, discontinuity=None)
        if src.discontinuity == RESUMED:  # the estimates go on, the filters restart
            self.run.restart_filters(float(src.meas.t[0]))
        elif src.discontinuity is not None:
            self.run.reset_estimators()
        b = self.run.process(src)
        block.shared["stage"] = b
        return _outputs(b, block), []

    def state(self) -> StageRunState:
        return self.run.state()

    def restore(self, state: object) -> None:
        if not isinstance(state, StageRunState):
            from common.errors import ParameterError

            raise ParameterError("state.parts.stage", "a StageRunState", type(state).__name__)
        self.run.restore(state)


def _outputs(b: StageBlock, block: Block) -> dict[str, F64]:
    """The stage's channels of one block, in :attr:`StagePart.channels` order."""
    th_a, th_s, sg, n = b.theta_adaptive, b.theta_switching, b.segment, block.n
    out: dict[str, F64] = {
        "f_true": b.f_true,
        "f_fixed": b.f_fixed,
        "f_adaptive": b.f_adaptive,
        "f_switching": b.f_switching,
        "f_segment": b.f_segment,
    }
    for j, q in enumerate(("J_L", "B_L", "F_CL")):
        out[f"{q}_true"] = getattr(b.truth, q)
        out[f"{q}_adaptive"] = th_a[:, j]
        out[f"{q}_switching"] = th_s[:, j]
        out[f"{q}_seg"] = sg.theta[:, j]
        out[f"{q}_lo"] = sg.lower[:, j]
        out[f"{q}_hi"] = sg.upper[:, j]
        out[f"{q}_excited"] = sg.excited[:, j].astype(np.float64)
    out["mode_switching"] = b.mode_switching.astype(np.float64)
    out["excitation"] = np.full(n, float(b.excitation_index))
    out["omega_l"] = b.truth.omega_l
    out["spindle_rpm"] = np.full(n, block.machine.spindle_rpm)
    out["q_m"] = b.meas.q_m
    out["x_l"] = b.meas.q_l * (SCREW_LEAD / (2 * math.pi))
    return out


def _needs_prior(machine: MachineView) -> Verdict:
    """The first two-inertia axis gives the observers' nominal (J_M, K, ...): without it
    the observers would run on another machine's parameters."""
    ax = next((a for a in machine.axes if a.kind == "two_inertia"), None)
    if ax is None or ax.prior:
        return OK
    return refuse(
        f"needs the nominal two-inertia parameters of axis {ax.name} (J_M, J_L, K, K_t, B_M, "
        "B_L, F_CM, F_CL) to design its observers; the feed's description gives none"
    )
