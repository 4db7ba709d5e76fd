"""Every axis of a described machine identified live as a rigid axis (issue 30, item 3).

:class:`AxisPart` runs :class:`server.pipeline.axis_identification.AxisIdentification`
on the columns of a machine's feed (``SourceBlock.columns``, by its source's names; a
source without them: its measurements by role): per axis ``<axis>.M``, ``.Fv``,
``.Fc``, ``.offset`` with their 95 % Newey-West intervals (``_lo``, ``_hi``) and
excitation (``_excited``), the friction of each direction, and the process force
``<axis>.F`` (the effort less the identified model) with its standard uncertainty
``<axis>.F_sd``. It is built for a live feed (its meta describes the machine), not for
the simulator's stage nor a replayed log (one two-inertia axis with its nominal, which
the stage part's observers watch: their streams stay as they were).

What it does not run, and why (the mass at 10 Hz without an exported acceleration, an
effect a live model cannot hold), is :meth:`AxisPart.notes`, per axis; the pipeline's
snapshot carries it (``axes``). A break in the feed restarts the filters and keeps the
estimates (the machine is the same). A change of the sample rate (a new meta)
designs every identifier again for the new rate, keeps the identified parameters, their
information and their rows, restarts the filters (:meth:`AxisPart.carry`,
:meth:`estimators.rigid_id.RigidIdentifier.adopt`) and says so in the part's status.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from common.machine_description import MachineDescription
from estimators.rigid_id import LiveEffect, RigidIdState
from server.pipeline.axis_identification import AxisIdentification
from server.pipeline.machine_view import MachineView
from server.pipeline.part import Block, Channel, Chart, LivePart, Outputs, Verdict, refuse

#: the roles a replayed log's measurements give by name (a one-axis log's columns)
_ROLES = ("q_m", "q_l", "tau_m", "i_m", "f_ext")


class AxisPart(LivePart):
    """The live rigid identification of every axis of ``machine`` (module docstring)."""

    name = "axes"

    def __init__(
        self,
        machine: MachineDescription,
        effects: Mapping[str, Sequence[LiveEffect]] | None = None,
    ) -> None:
        self.machine = machine
        self.effects = {k: tuple(v) for k, v in (effects or {}).items()}
        self.ident = AxisIdentification(machine, self.effects)
        self.ident_state: dict[str, RigidIdState] = self.ident.initial_state()
        self.channels, self.charts = _declare(self.ident)
        #: what the part says beside running (a rate change it followed)
        self.said = ""

    def requires(self, machine: MachineView) -> Verdict:
        if any(a.has("q_m") and (a.has("tau_m") or a.has("i_m")) for a in machine.axes):
            return super().requires(machine)
        return refuse(
            f"needs an axis with q_m and tau_m or i_m; the {machine.source} source's "
            "machine has none"
        )

    def notes(self) -> dict[str, dict[str, str]]:
        """Per axis, what does not run and why."""
        return self.ident.reasons

    def carry(self, old: AxisPart, t: float) -> None:
        """Take ``old``'s identified parameters (a pipeline built again for a new meta):
        per axis of the same name, the estimate, its information and rows kept, the
        filters restarted (:meth:`estimators.rigid_id.RigidIdentifier.adopt`)."""
        kept = []
        for a in self.ident.axes:
            name = a.desc.name
            prev = next((o for o in old.ident.axes if o.desc.name == name), None)
            if prev is None:
                continue
            self.ident_state[name] = a.ident.adopt(old.ident_state[name], prev.ident.names)
            kept.append(name)
        ts0, ts1 = old.machine.sample_time, self.machine.sample_time
        if kept and ts0 != ts1:
            self.said = (
                f"designed again at t = {t:.3f} s for {1 / ts1:g} Hz (was {1 / ts0:g} Hz): "
                f"identified parameters of {', '.join(kept)} kept, filter states restarted"
            )

    def step(self, block: Block) -> Outputs:
        src = block.source
        if src.discontinuity is not None:  # the same machine: the estimates go on
            self.ident_state = self.ident.restart_filters(self.ident_state)
        cols = src.columns or {r: getattr(src.meas, r) for r in _ROLES}
        t = np.asarray(src.meas.t, dtype=np.float64)
        self.ident_state, out = self.ident.step(self.ident_state, t, cols)
        return out, []

    def state(self) -> dict[str, RigidIdState]:
        return self.ident_state

    def restore(self, state: Any) -> None:
        self.ident_state = dict(state)

    def status(self) -> dict[str, object]:
        return {}


def _declare(ident: AxisIdentification) -> tuple[tuple[Channel, ...], tuple[Chart, ...]]:
    """The channels (every one :meth:`AxisIdentification.channels` gives) and, per axis,
    its charts: the process force (operator page, fast), the friction and the mass with
    their 95 % bands (research page)."""
    chans = {c.name: Channel(c.name, c.unit, c.label, c.group) for c in ident.channels()}
    charts: list[Chart] = []
    drawn: list[Channel] = []
    for i, a in enumerate(ident.axes):
        n = a.desc.name
        force = Chart(f"axis-{n}-force", f"{n}: process force (effort less the identified "
                      "rigid model)", page="operator", order=40 + i, fast=True)  # fmt: skip
        fric = Chart(f"axis-{n}-friction", f"{n}: friction identified live (95 % Newey-West)",
                     order=60 + i)  # fmt: skip
        mass = Chart(f"axis-{n}-mass", f"{n}: mass (inertia) identified live", order=70 + i)
        charts += [force, fric, mass]
        drawn += force.series(
            _with(chans[f"{n}.F"], legend="F", color="#1e88e5"),
            _with(chans[f"{n}.F_sd"], legend="F sd", color="#9e9e9e", dash=(4.0, 3.0)),
        )
        drawn += fric.series(_banded(chans, n, "Fc"), _banded(chans, n, "Fv", axis_name="Fv"))
        drawn += mass.series(_banded(chans, n, "M"))
    by_name = {c.name: c for c in drawn}
    return tuple(by_name.get(c, ch) for c, ch in chans.items()), tuple(charts)


def _with(c: Channel, **kw: Any) -> Channel:
    from dataclasses import replace

    return replace(c, **kw)


def _banded(chans: Mapping[str, Channel], axis: str, k: str, axis_name: str = "") -> Channel:
    base = f"{axis}.{k}"
    return _with(
        chans[base],
        interval=(f"{base}_lo", f"{base}_hi", f"{base}_excited"),
        legend=k,
        axis=axis_name,
    )
