"""Seed 000's two-inertia cutting force observer on a described machine's axis with a
linear scale, from parameters identified on the trace (issue 31 item 2).

The stage part's observers (:mod:`server.pipeline.stage_part`) are designed from the
nominal two-inertia parameters a description may give; a CNC gives none, so on the
machining centre they do not run. :class:`TwoInertiaAxisPart` builds seed 000's
structure from what the axis' own signals identify, per two-inertia axis (motor encoder
``q_m``, scale ``q_l``, effort):

1. the **motor side** (:class:`estimators.twist_id.TwistIdentifier`): the motor-side
   mass, friction and the drive train's stiffness :math:`K` from
   :math:`\\tau = M_M\\ddot q_M + K(q_M - q_L) + B_M\\dot q_M + F_{CM}\\,\\mathrm{sgn} + c`,
   which holds in the cut as in the air;
2. the **torsional force** :math:`\\hat T_s = \\hat K (q_M - q_L)` (seed 000 (4), the
   load-side relation: its ``mix="twist"``, as the stage part uses below 625 Hz);
3. the **load side and the cutting force** (seed 000 (2)):
   :math:`\\hat F = Q[\\hat T_s] - Q[\\hat M_L s v_L + \\hat B_L v_L + \\hat F_{CL}
   \\mathrm{sgn}\\,v_L]`, with :math:`M_L, B_L, F_{CL}` identified by
   :class:`estimators.rigid_id.RigidIdentifier` on the scale with :math:`\\hat T_s` as
   its effort, learnt only in the air (where the spindle's cutting power, the ``spindle``
   part's, is under :data:`server.pipeline.axis_monitor_part.CUT_W`: in a cut the
   process force would be taken into the load's model). Q(s) is that identifier's
   parallel filter: :math:`(\\omega_c/(s+\\omega_c))^4` at a tenth of the rate, 50 Hz
   at 500 Hz (-3 dB at ~22 Hz, 12.7 ms of lag). Seed 000's Q (first order, 250 Hz at
   2.5 kHz) would sit on a 500 Hz trace's Nyquist frequency; the twist measures the
   spring's force at every frequency, so Q need not be below the axial mode (130 Hz on
   the centre's X), only the accelerations' differences need the filter.

Per axis it streams ``<axis>.F_2i`` (the process force) with ``<axis>.F_2i_sd``,
``<axis>.K``, ``<axis>.M_M``, ``<axis>.M_L``, ``<axis>.B_L``, ``<axis>.F_CL`` and the
mode they give, ``<axis>.mode_hz``. Below 100 Hz it says why it cannot run (an
acceleration is not had by differencing there).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from common.errors import ParameterError
from common.machine_description import MachineDescription
from estimators.residual.rate import LOW_RATE_HZ
from estimators.rigid_id import RigidIdentifier, RigidIdState, rigid_design
from estimators.twist_id import TwistIdentifier, TwistIdParams, TwistIdState, mode_hz
from server.pipeline.axis_monitor_part import CUT_W
from server.pipeline.estimates_out import StatusStrip
from server.pipeline.machine_view import MachineView
from server.pipeline.part import (
    Block,
    Channel,
    Chart,
    LivePart,
    Outputs,
    Verdict,
    column_or,
    nan_channels,
    refuse,
)

__all__ = ["TwoInertiaAxisPart", "TwoInertiaState", "two_inertia_axes"]


def two_inertia_axes(description: MachineDescription) -> tuple[str, ...]:
    """The axes seed 000's structure can be identified on: two-inertia, with the motor
    encoder, the scale and an effort."""
    return tuple(
        a.name
        for a in description.axes
        if a.kind == "two_inertia"
        and {"q_m", "q_l"} <= set(a.signals)
        and ("tau_m" in a.signals or ("i_m" in a.signals and a.K_t is not None))
    )


@dataclass
class TwoInertiaState:
    """Per axis the motor side's and the load side's identifier states."""

    motor: dict[str, TwistIdState] = field(default_factory=dict)
    load: dict[str, RigidIdState] = field(default_factory=dict)


def _declare(axes: tuple[str, ...]) -> tuple[tuple[Chart, ...], tuple[Channel, ...]]:
    charts: list[Chart] = []
    chans: list[Channel] = []
    for i, a in enumerate(axes):
        force = Chart(
            f"axis-{a}-two-inertia",
            f"{a}: process force of seed 000's two-inertia observer (the twist K (q_m - q_l) "
            "less the load's identified model, Q(s) at a tenth of the rate)",
            order=45 + i,
        )
        params = Chart(
            f"axis-{a}-two-inertia-params",
            f"{a}: two-inertia parameters identified on the trace",
            order=75 + i,
        )
        charts += [force, params]
        chans += force.series(
            Channel(
                f"{a}.F_2i",
                "N",
                f"{a} process force, two-inertia observer",
                "force",
                color="#d81b60",
                legend="F, two-inertia",
            ),
            Channel(
                f"{a}.F_2i_sd",
                "N",
                f"{a} process force (two-inertia), standard uncertainty",
                "force_sd",
                color="#9e9e9e",
                dash=(4.0, 3.0),
                legend="F sd",
            ),
        )
        chans += params.series(
            Channel(
                f"{a}.mode_hz",
                "Hz",
                f"{a} first axial mode from K, M_M, M_L",
                f"{a}.two_inertia",
                legend="mode [Hz]",
            ),
        )
        chans += (
            Channel(f"{a}.K", "N/m", f"{a} drive train stiffness", f"{a}.two_inertia"),
            Channel(f"{a}.M_M", "kg", f"{a} motor-side mass", f"{a}.two_inertia"),
            Channel(f"{a}.M_L", "kg", f"{a} load mass", f"{a}.two_inertia"),
            Channel(f"{a}.B_L", "N s/m", f"{a} load viscous friction", f"{a}.two_inertia"),
            Channel(f"{a}.F_CL", "N", f"{a} load Coulomb friction", f"{a}.two_inertia"),
        )
    return tuple(charts), tuple(chans)


class TwoInertiaAxisPart(LivePart):
    """Seed 000's observer on every two-inertia axis of ``description`` (module docstring)."""

    name = "two_inertia"
    needs = ("spindle",)

    def __init__(self, description: MachineDescription) -> None:
        self.description = description
        self.axes = two_inertia_axes(description)
        self.sample_time = float(description.sample_time)
        self.charts, self.channels = _declare(self.axes)
        #: what the part says beside running (a rate change it followed)
        self.said = ""
        self._why = ""
        if 1.0 / self.sample_time < LOW_RATE_HZ:
            self._why = (
                f"at {1.0 / self.sample_time:g} Hz the accelerations of the motor and the load "
                f"cannot be had by differencing (needs {LOW_RATE_HZ:g} Hz or more)"
            )
            return
        params, _ = rigid_design(self.sample_time)
        self.load = RigidIdentifier(params)
        self.motor = TwistIdentifier(TwistIdParams(self.sample_time, filter_hz=params.filter_hz))
        self._ax = {a.name: a for a in description.axes}
        self.st = TwoInertiaState(
            {a: self.motor.initial_state() for a in self.axes},
            {a: self.load.initial_state() for a in self.axes},
        )

    def requires(self, machine: MachineView) -> Verdict:
        if not self.axes:
            return refuse("needs a two-inertia axis with q_m, q_l and an effort")
        if self._why:
            return refuse(self._why)
        return super().requires(machine)

    def _effort(self, axis: str, cols: Any) -> np.ndarray:
        ax = self._ax[axis]
        s = ax.signals
        if "tau_m" in s:
            return np.asarray(cols[s["tau_m"]], dtype=np.float64)
        return np.asarray(cols[s["i_m"]], dtype=np.float64) * float(ax.K_t or 1.0)

    def step(self, block: Block) -> Outputs:
        n = block.n
        out = nan_channels(self.channels, n)
        cols = block.source.columns or {}
        if self._why or not cols:
            return out, []
        src = block.source
        if src.discontinuity is not None:
            self.st.motor = {a: self.motor.restart_filters(s) for a, s in self.st.motor.items()}
            self.st.load = {a: self.load.restart_filters(s) for a, s in self.st.load.items()}
        cut = np.asarray(column_or(block.outputs, "spindle_cut", n, math.nan))
        with np.errstate(invalid="ignore"):
            air = np.isfinite(cut) & (cut <= CUT_W)
        t = np.asarray(src.meas.t, dtype=np.float64)
        for a in self.axes:
            s = self._ax[a].signals
            qm = np.asarray(cols[s["q_m"]], dtype=np.float64)
            ql = np.asarray(cols[s["q_l"]], dtype=np.float64)
            k_before = float(self.st.motor[a].theta[1])
            self.st.motor[a] = self.motor.step(self.st.motor[a], qm, ql, self._effort(a, cols))
            th = self.st.motor[a].theta
            if not math.isfinite(k_before) or k_before <= 0:
                continue  # the stiffness is not known yet: no twist force
            twist = k_before * (qm - ql)
            self.st.load[a], rec = self.load.step(self.st.load[a], t, ql, twist, learn=air)
            out[f"{a}.F_2i"] = rec.force
            out[f"{a}.F_2i_sd"] = rec.force_sd
            m_l, b_l, f_cl = (float(rec.theta[i]) for i in range(3))
            for k, v in (("K", th[1]), ("M_M", th[0]), ("M_L", m_l), ("B_L", b_l),
                         ("F_CL", f_cl), ("mode_hz", mode_hz(th[1], th[0], m_l))):  # fmt: skip
                out[f"{a}.{k}"] = np.full(n, float(v))
        return out, []

    def carry(self, old: TwoInertiaAxisPart, t: float) -> None:
        """Take ``old``'s identified parameters (a pipeline built again for a new meta, a
        new rate): per axis of the same name, the motor side's estimate and information
        (its columns are in physical units whatever the rate) and the load side's
        (:meth:`estimators.rigid_id.RigidIdentifier.adopt`), the filters restarted."""
        if self._why or old._why:
            return
        kept = []
        for a in self.axes:
            if a not in old.st.motor:
                continue
            self.st.motor[a] = self.motor.restart_filters(old.st.motor[a])
            self.st.load[a] = self.load.adopt(old.st.load[a], old.load.names)
            kept.append(a)
        if kept and old.sample_time != self.sample_time:
            self.said = (
                f"designed again at t = {t:.3f} s for {1 / self.sample_time:g} Hz (was "
                f"{1 / old.sample_time:g} Hz): K, M_M, M_L, B_L, F_CL of {', '.join(kept)} "
                "kept, filter states restarted"
            )

    def status(self) -> StatusStrip:
        return {}

    def state(self) -> TwoInertiaState | None:
        return None if self._why else self.st

    def restore(self, state: object) -> None:
        if state is None:
            return
        if not isinstance(state, TwoInertiaState):
            raise ParameterError(
                "state.parts.two_inertia", "a TwoInertiaState", type(state).__name__
            )
        self.st = state
