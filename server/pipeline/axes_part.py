"""Every feed axis of a described machine, identified live as a rigid axis, with its process
force: :class:`server.pipeline.axis_identification.AxisIdentification` as a live part.

:class:`AxesPart` (issue 31 phase 2, step d) builds one rigid identifier per axis of the
source's machine description (designed from the trace's rate and the signals the axis
gives) and streams, per axis ``A``: the process force ``A_F`` with its standard
uncertainty ``A_F_sd`` (the operator's chart "Axes: process force"), and the identified
mass, viscous and Coulomb friction and effort offset, each with its 95 % interval and
excitation flag (``A_M``, ``A_M_lo``, ``A_M_hi``, ``A_M_excited``...; a chart per axis on
the research page). What does not run on an axis, and why, is in
:attr:`AxesPart.reasons` and in the part's status line (e.g. the mass without an
acceleration at a slow trace).

The channels are named ``<axis>_<name>`` (the identification's ``<axis>.<name>`` with
the dot replaced: a channel's name is a key in the page's element ids). The factory
builds it only for a source that carries a machine description with its columns (the
machining centre), so the stage's scenarios stream what they did.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from common.errors import ParameterError
from common.machine_description import MachineDescription
from server.pipeline.axis_identification import AxisIdentification
from server.pipeline.machine_view import MachineView
from server.pipeline.part import OK, Block, Channel, Chart, LivePart, Outputs, Verdict, refuse

__all__ = ["AXES_FORCE", "AxesPart"]

AXES_FORCE = Chart(
    "axes_force",
    "Axes: process force from the rigid identification (motor current less the "
    "identified inertia, friction and offset)",
    page="operator",
    order=15,
    window_s=30.0,
    wide=True,
    markers=True,
)
#: one colour per axis
_AXIS_COLORS = ("#0072b2", "#d55e00", "#009e73", "#cc79a7")
_PARAM_LABEL = {"M": "mass", "Fv": "viscous friction", "Fc": "Coulomb friction",
                "offset": "effort offset"}  # fmt: skip


def _key(name: str) -> str:
    return name.replace(".", "_")


def _channels(ident: AxisIdentification) -> tuple[tuple[Channel, ...], tuple[Chart, ...]]:
    """The channels (process forces on the operator's chart, each parameter with its
    interval on its axis' chart) and the charts."""
    forces: list[Channel] = []
    charts: list[Chart] = [AXES_FORCE]
    rest: list[Channel] = []
    by = {c.name: c for c in ident.channels()}
    for i, ax in enumerate(ident.machine.axes):
        a = ax.name
        color = _AXIS_COLORS[i % len(_AXIS_COLORS)]
        f = by[f"{a}.F"]
        forces.append(Channel(_key(f.name), f.unit, f.label, "axes_force", color=color,
                              legend=f"{a} [{f.unit}]"))  # fmt: skip
        chart = Chart(f"axis_{a}", f"Axis {a}: identified parameters with their 95 % "
                      "intervals", page="research", order=60 + i)  # fmt: skip
        charts.append(chart)
        drawn = []
        for k in ("M", "Fv", "Fc"):
            c = by[f"{a}.{k}"]
            name = _key(c.name)
            drawn.append(Channel(name, c.unit, c.label, "axis_params", axis=k,
                                 interval=(f"{name}_lo", f"{name}_hi", f"{name}_excited"),
                                 legend=f"{_PARAM_LABEL[k]} [{c.unit}]"))  # fmt: skip
        rest += chart.series(*drawn)
        shown = {c.name for c in drawn} | {f.name}
        rest += [Channel(_key(c.name), c.unit, c.label, "axis_params")
                 for c in ident.channels() if c.name.startswith(f"{a}.")
                 and _key(c.name) not in shown]  # fmt: skip
    return (*AXES_FORCE.series(*forces), *rest), tuple(charts)


class AxesPart(LivePart):
    """The axes' rigid identification and process force (module docstring).

    Parameters
    ----------
    description
        The machine's description: its axes, their signals' columns, the rate.
    """

    name = "axes"

    def __init__(self, description: MachineDescription) -> None:
        self.ident = AxisIdentification(description)
        self.channels, self.charts = _channels(self.ident)
        self.id_state = self.ident.initial_state()

    @property
    def reasons(self) -> dict[str, dict[str, str]]:
        """Per axis, what of its identification does not run and why."""
        return self.ident.reasons

    def requires(self, machine: MachineView) -> Verdict:
        if not machine.axes:
            return refuse("needs a described machine with feed axes")
        return OK

    def step(self, block: Block) -> Outputs:
        cols = block.source.columns
        if not cols:
            nan = block.held(float("nan"))
            return {c.name: nan for c in self.channels}, []
        if block.discontinuity is not None:
            self.id_state = self.ident.restart_filters(self.id_state)
        t = np.asarray(cols.get("t", block.t), dtype=np.float64)
        self.id_state, out = self.ident.step(self.id_state, t, cols)
        return {_key(k): v for k, v in out.items()}, []

    def state(self) -> Any:
        return self.id_state

    def restore(self, state: object) -> None:
        if not isinstance(state, dict):
            raise ParameterError("state.parts.axes", "the axes' identifier states", state)
        self.id_state = state
