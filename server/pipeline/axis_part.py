"""Every axis of a described machine identified live as a rigid axis (issue 30, item 3).

:class:`AxisPart` runs :class:`server.pipeline.axis_identification.AxisIdentification`
on the columns of a machine's feed (``SourceBlock.columns``, by its source's names; a
source without them: its measurements by role): per axis ``<axis>.M``, ``.Fv``,
``.Fc``, ``.offset`` with their 95 % Newey-West intervals (``_lo``, ``_hi``) and
excitation (``_excited``), the friction of each direction, and the process force
``<axis>.F`` (the effort less the identified model) with its standard uncertainty
``<axis>.F_sd``. It is built for a described machine (a feed's meta), not for the
simulator's stage nor for a machine whose every axis is two-inertia with its nominal
(the stage part's observers watch it, and it streams the same fed or replayed).

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
from server.pipeline.estimates_out import StatusStrip
from server.pipeline.machine_view import MachineView
from server.pipeline.part import Block, Channel, Chart, LivePart, Outputs, Verdict, refuse

#: the key of effects meant for every axis (a ``--model REPORT.json`` without ``AXIS=``)
ALL_AXES = "*"

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
        every = self.effects.get(ALL_AXES, ())  # a report given without its axis: each axis'
        self.effects = {a.name: self.effects.get(a.name, every) for a in machine.axes}
        self.ident = AxisIdentification(machine, self.effects)
        self.ident_state: dict[str, RigidIdState] = self.ident.initial_state()
        #: the axes whose model holds a report's effects, and beside them the same axes
        #: identified without (their process force ``<axis>.F_base``: the dashboard shows
        #: the residual with and without the report)
        self.with_effects = tuple(
            a.desc.name for a in self.ident.axes if self.effects.get(a.desc.name)
        )
        self.base = AxisIdentification(machine) if self.with_effects else None
        self.base_state = self.base.initial_state() if self.base is not None else {}
        self.channels, self.charts = _declare(self.ident, self.with_effects)
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
            if self.base is not None:  # without the effects: the old model's base columns
                src, names = old.ident_state[name], prev.ident.names
                if old.base is not None and name in old.base_state:
                    src = old.base_state[name]
                    names = next(b for b in old.base.axes if b.desc.name == name).ident.names
                b = next(x for x in self.base.axes if x.desc.name == name)
                self.base_state[name] = b.ident.adopt(src, names)
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
            if self.base is not None:
                self.base_state = self.base.restart_filters(self.base_state)
        cols = src.columns or {r: getattr(src.meas, r) for r in _ROLES}
        t = np.asarray(src.meas.t, dtype=np.float64)
        self.ident_state, out = self.ident.step(self.ident_state, t, cols)
        if self.base is not None:
            self.base_state, base = self.base.step(self.base_state, t, cols)
            for n in self.with_effects:
                out[f"{n}.F_base"] = base[f"{n}.F"]
        return out, []

    def state(self) -> dict[str, dict[str, RigidIdState]]:
        return {"ident": self.ident_state, "base": self.base_state}

    def restore(self, state: Any) -> None:
        self.ident_state = dict(state["ident"])
        self.base_state = dict(state["base"])

    def status(self) -> StatusStrip:
        return {}


def _declare(
    ident: AxisIdentification, with_effects: Sequence[str]
) -> tuple[tuple[Channel, ...], tuple[Chart, ...]]:
    """The channels (every one :meth:`AxisIdentification.channels` gives, and the process
    force without the report's effects of the axes ``with_effects``) and, per axis, its
    charts: the effort and the process force (operator page, fast), the friction and the
    mass with their 95 % bands (research page)."""
    chans = {c.name: Channel(c.name, c.unit, c.label, c.group) for c in ident.channels()}
    for n in with_effects:
        f = chans[f"{n}.F"]
        chans[f"{n}.F_base"] = Channel(
            f"{n}.F_base", f.unit, f"{n} process force without the report's effects", "force"
        )
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
        fx = n in with_effects
        drawn += force.series(
            _with(chans[f"{n}.effort"], legend="effort", color="#bdbdbd", width=1.0),
            *(
                (
                    _with(
                        chans[f"{n}.F_base"],
                        legend="F without the report",
                        color="#e53935",
                        dash=(5.0, 3.0),
                    ),
                )
                if fx
                else ()
            ),
            _with(chans[f"{n}.F"], legend="F with the report" if fx else "F", color="#1e88e5"),
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


def axis_models(specs: str | Sequence[str]) -> dict[str, tuple[LiveEffect, ...]]:
    """The effects each ``[AXIS=]REPORT.json`` selected (``cutwatch serve --model``;
    comma-separated or a list), by axis (:data:`ALL_AXES` without ``AXIS=``).

    Raises
    ------
    CutwatchError
        A file that cannot be read, not JSON, or not a rigid residual report (named).
    """
    import json
    from pathlib import Path

    from server.errors import CutwatchError
    from server.records.residual_report import live_effects

    items = specs.split(",") if isinstance(specs, str) else list(specs)
    out: dict[str, tuple[LiveEffect, ...]] = {}
    for spec in (x.strip() for x in items):
        if not spec:
            continue
        axis, sep, path = spec.partition("=")
        if not sep:
            axis, path = ALL_AXES, spec
        try:
            rep = json.loads(Path(path).read_text())
        except (OSError, ValueError) as exc:
            raise CutwatchError(
                f"model {spec!r}: expected [AXIS=]REPORT.json, a residual report; {exc}"
            ) from None
        out[axis] = tuple(live_effects(rep, f"model {spec!r}"))
    return out
