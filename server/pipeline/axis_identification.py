"""Every axis of a described machine identified live as a rigid axis, with its process force.

For each axis of a :class:`common.machine_description.MachineDescription` one
:class:`estimators.rigid_id.RigidIdentifier`, designed from the machine's rate and the
signals the axis has (:func:`estimators.rigid_id.rigid_design`): the motor position
``q_m`` and the effort (``tau_m``, else the current ``i_m``, times ``K_t`` when it is
known); below 100 Hz the CNC's velocity and acceleration (the actual ones, else the
commanded ones). A residual report's effects for an axis (``effects``) join its model.
A two-inertia axis is identified here too, as the rigid axis its motor side is below the
torsion (its two-inertia observers are another part's).

:meth:`AxisIdentification.step` takes one block of the feed's columns (by source name)
and returns, per sample, every axis' ``M``, ``Fv``, ``Fc``, ``offset`` with their 95 %
interval (``_lo``, ``_hi``) and excitation (``_excited``), the friction of each
direction (``Fc_pos``, ``Fc_neg``), and the process force ``F`` with its standard
uncertainty ``F_sd`` (and the filtered effort it is taken from, ``effort``), the
velocity reversals and the seconds of motion learnt from
(``reversals``, ``moving_s``), as channels named ``<axis>.<name>``;
:attr:`AxisIdentification.reasons` says, per axis, what does not run and why (the mass at
10 Hz without an acceleration, an effect a live model cannot hold).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from common.arrays import F64
from common.machine_description import AxisDescription, MachineDescription
from estimators.rigid_id import (
    BASE,
    LiveEffect,
    RigidIdentifier,
    RigidIdRecord,
    RigidIdState,
    rigid_design,
)

#: the per-axis channels besides the parameters' (value, _lo, _hi, _excited)
EXTRA = ("Fc_pos", "Fc_neg", "F", "F_sd", "effort", "reversals", "moving_s")


@dataclass(frozen=True)
class AxisChannel:
    """One channel of the axes' identification: its name, unit, label and group."""

    name: str
    unit: str
    label: str
    group: str


def _units(ax: AxisDescription) -> dict[str, str]:
    """The parameters' units: the effort's (N, N m, or A without a torque constant)
    over the position's derivatives."""
    eff = ax.effort_unit if ("tau_m" in ax.signals or ax.K_t is not None) else "A"
    p = ax.position_unit
    return {"M": f"{eff} s^2/{p}", "Fv": f"{eff} s/{p}", "Fc": eff, "offset": eff, "F": eff}


@dataclass
class _Axis:
    desc: AxisDescription
    ident: RigidIdentifier
    effort: str  # the source of the effort
    scale: float  # K_t when the effort is a current with a known torque constant
    velocity: str | None
    acceleration: str | None
    reasons: dict[str, str]


class AxisIdentification:
    """The live rigid identification of every axis of ``machine`` (module docstring)."""

    def __init__(
        self,
        machine: MachineDescription,
        effects: Mapping[str, Sequence[LiveEffect]] | None = None,
    ) -> None:
        self.machine = machine
        self.axes = [self._axis(ax, (effects or {}).get(ax.name, ())) for ax in machine.axes]

    def _axis(self, ax: AxisDescription, effects: Sequence[LiveEffect]) -> _Axis:
        s = ax.signals
        vel = s.get("qd_m") or s.get("qd_cmd")
        acc = s.get("qdd_m") or s.get("qdd_cmd")
        params, reasons = rigid_design(
            self.machine.sample_time,
            velocity_given=vel is not None,
            acceleration_given=acc is not None,
            effects=effects,
        )
        current = "tau_m" not in s
        scale = ax.K_t if current and ax.K_t is not None else 1.0
        effort = s["i_m"] if current else s["tau_m"]
        return _Axis(ax, RigidIdentifier(params), effort, scale, vel, acc, reasons)

    @property
    def reasons(self) -> dict[str, dict[str, str]]:
        """Per axis, what does not run and why."""
        return {a.desc.name: dict(a.reasons) for a in self.axes}

    def channels(self) -> list[AxisChannel]:
        """Every channel :meth:`step` returns, in order."""
        out: list[AxisChannel] = []
        for a in self.axes:
            u = _units(a.desc)
            n = a.desc.name
            for k in BASE:
                label = {"M": "mass (inertia)", "Fv": "viscous friction",
                         "Fc": "Coulomb friction", "offset": "effort offset"}[k]  # fmt: skip
                out += [
                    AxisChannel(f"{n}.{k}", u[k], f"{n} {label}", f"{n}.{k}"),
                    AxisChannel(f"{n}.{k}_lo", u[k], f"{n} {label}, 95 % lower", f"{n}.{k}"),
                    AxisChannel(f"{n}.{k}_hi", u[k], f"{n} {label}, 95 % upper", f"{n}.{k}"),
                    AxisChannel(f"{n}.{k}_excited", "", f"{n} {label} excited", f"{n}.{k}"),
                ]
            out += [
                AxisChannel(f"{n}.Fc_pos", u["Fc"], f"{n} friction, v > 0", f"{n}.Fc"),
                AxisChannel(f"{n}.Fc_neg", u["Fc"], f"{n} friction, v < 0", f"{n}.Fc"),
                AxisChannel(f"{n}.F", u["F"], f"{n} process force", "force"),
                AxisChannel(
                    f"{n}.F_sd", u["F"], f"{n} process force, standard uncertainty", "force_sd"
                ),
                AxisChannel(
                    f"{n}.effort", u["F"], f"{n} drive effort, filtered as the model", "effort"
                ),
                AxisChannel(
                    f"{n}.reversals", "", f"{n} velocity reversals learnt from", f"{n}.motion"
                ),
                AxisChannel(
                    f"{n}.moving_s", "s", f"{n} seconds of motion learnt from", f"{n}.motion"
                ),
            ]
        return out

    def initial_state(self) -> dict[str, RigidIdState]:
        return {a.desc.name: a.ident.initial_state() for a in self.axes}

    def restart_filters(self, state: dict[str, RigidIdState]) -> dict[str, RigidIdState]:
        """After a break in the feed: the filters start again, the estimates are kept."""
        return {a.desc.name: a.ident.restart_filters(state[a.desc.name]) for a in self.axes}

    def step(
        self,
        state: dict[str, RigidIdState],
        t: F64,
        columns: Mapping[str, F64],
        learn: Mapping[str, NDArray[np.bool_]] | None = None,
    ) -> tuple[dict[str, RigidIdState], dict[str, F64]]:
        """One block: ``t`` and the feed's columns by source name (``learn``: per axis, where
        it may learn). Returns the new state and the channels, ``len(t)`` values each."""
        n = len(t)
        new: dict[str, RigidIdState] = {}
        out: dict[str, F64] = {}
        for a in self.axes:
            name = a.desc.name
            kw = {}
            if a.ident.params.velocity == "given" and a.velocity is not None:
                kw["qd"] = columns[a.velocity]
            if a.ident.params.acceleration == "given" and a.acceleration is not None:
                kw["qdd"] = columns[a.acceleration]
            q = columns[a.desc.signals["q_m"]]
            eff = np.asarray(columns[a.effort], dtype=np.float64) * a.scale
            lm = None if learn is None else learn.get(name)
            new[name], rec = a.ident.step(state[name], t, q, eff, learn=lm, **kw)
            out.update(_channels(name, a.ident.names, rec, n))
        return new, out


def _channels(axis: str, names: Sequence[str], rec: RigidIdRecord, n: int) -> dict[str, F64]:
    """One axis' channels of a block: the estimate after the block held over it (the
    held values are the rows of one array: one allocation per axis and block)."""
    idx = {k: i for i, k in enumerate(names)}
    keys: list[str] = []
    vals: list[float] = []
    for k in BASE:
        i = idx.get(k)
        four = (math.nan, math.nan, math.nan, 0.0) if i is None else (
            rec.theta[i], rec.lower[i], rec.upper[i], float(rec.excited[i]))  # fmt: skip
        for suffix, v in zip(("", "_lo", "_hi", "_excited"), four):
            keys.append(f"{axis}.{k}{suffix}")
            vals.append(float(v))
    for d in ("Fc_pos", "Fc_neg"):
        keys.append(f"{axis}.{d}")
        vals.append(rec.directions.get(d, (math.nan, 0.0))[0])
    held = np.repeat(np.array(vals, dtype=np.float64)[:, None], n, axis=1)
    out: dict[str, F64] = {k: held[j] for j, k in enumerate(keys)}
    out[f"{axis}.F"] = rec.force
    out[f"{axis}.F_sd"] = rec.force_sd
    out[f"{axis}.effort"] = rec.effort
    tail = np.repeat(np.array([float(rec.reversals), float(rec.moving_time)])[:, None], n, axis=1)
    out[f"{axis}.reversals"] = tail[0]
    out[f"{axis}.moving_s"] = tail[1]
    return out
