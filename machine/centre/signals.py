"""The machining centre's signals as a CNC names them: its machine description, in one place.

Everything that says which simulated signal is which CNC signal lives here: the column
name of each signal in a drive block or a measured log, its role and unit in the machine
description (issue 30: ``common/machine.schema.json``: ``axes`` with ``kind``,
``signals``, ``units``; ``spindle``; ``identities``; ``sample_time``), and which of the
simulator's rows are truth (never handed to an estimator). :func:`description` returns
the description read and checked by :mod:`common.machine_description`.

Columns: per axis ``<A>_<role>`` (``X_q_m``, ``X_q_l``, ``X_q_cmd``, ``X_qd_m``,
``X_i_m``; Y and Z without ``q_l``: semi-closed loop), the spindle ``S_speed``,
``S_speed_cmd``, ``S_current``, ``S_power``, and the identities ``tool``, ``line``,
``override`` (the program's name is the record's, a sidecar key). Truth columns carry
the prefix ``true_`` (``true_X_f_process``, ``true_S_torque_cut``, ``true_engaged``,
``true_vb``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from common.arrays import F64
from common.machine_description import MachineDescription, from_dict
from common.state_io import JsonNode
from machine.centre.params import CentreParams

#: the roles an axis exports, by kind (what a CNC's trace gives per axis)
AXIS_ROLES = {
    "two_inertia": ("q_m", "q_l", "q_cmd", "qd_m", "i_m"),
    "rigid": ("q_m", "q_cmd", "qd_m", "i_m"),
}
#: the spindle's roles, its simulator row and unit
SPINDLE_SIGNALS = {
    "speed": ("S.speed", "rpm"),
    "speed_cmd": ("S.speed_cmd", "rpm"),
    "current": ("S.current", "A"),
    "power": ("S.power", "W"),
}
#: truth rows exported beside the measurements (for display and scoring only)
TRUTH_ROWS = (
    "X.f_process", "Y.f_process", "Z.f_process", "X.x_load", "Y.x_load", "Z.x_load",
    "S.torque_cut", "S.speed_true", "engaged",
)  # fmt: skip
#: the identities' columns
IDENTITIES = ("tool", "line", "override")


def column(owner: str, role: str) -> str:
    """The column of a signal: ``X_q_m``, ``S_power``."""
    return f"{owner}_{role}"


def truth_column(row: str) -> str:
    """The column of a truth row: ``X.f_process`` -> ``true_X_f_process``."""
    return "true_" + row.replace(".", "_")


def description(params: CentreParams | None = None, rate_hz: float = 500.0) -> MachineDescription:
    """The machine description of the centre's trace at ``rate_hz``, checked against the
    schema (:func:`description_dict` is the same as a dict)."""
    return from_dict(description_dict(params, rate_hz))


def description_dict(
    params: CentreParams | None = None, rate_hz: float = 500.0
) -> dict[str, JsonNode]:
    """The machine description of the centre's trace at ``rate_hz`` (issue 30's schema).

    Per axis its kind, its columns by role, units (m, N: efforts are motor currents [A]
    with the force constant ``K_t`` [N/A] known from the motor data), the motor encoder's
    resolution along the axis; no nominal (a prior is never required).
    """
    p = params if params is not None else CentreParams()
    axes: dict[str, JsonNode] = {}
    for ax in p.axes:
        axes[ax.name] = {
            "kind": ax.kind,
            "signals": {r: column(ax.name, r) for r in AXIS_ROLES[ax.kind]},
            "units": {"position": "m", "effort": "N"},
            "K_t": ax.force_constant,
            "encoder_resolution": ax.encoder_quantum,
        }
    return {
        "sample_time": 1.0 / rate_hz,
        "axes": axes,
        "spindle": {
            "signals": {r: column("S", r) for r in SPINDLE_SIGNALS},
            # the commanded speed's unit is the speed's (the schema names no other)
            "units": {r: u for r, (_, u) in SPINDLE_SIGNALS.items() if r != "speed_cmd"},
        },
        "identities": {
            "program": "program",
            "tool": "tool",
            "line": "line",
            "override": "override",
        },
    }


def columns(rec: Any, params: CentreParams | None = None, *, truth: bool = False) -> dict[str, F64]:
    """The measured columns of a record (a :class:`machine.centre.trace.TraceRecord` or a
    :class:`machine.centre.sim.CentreRecord`) by column name; with ``truth`` also the
    truth columns. ``t`` first, then the axes, the spindle, the identities."""
    p = params if params is not None else CentreParams()
    out: dict[str, F64] = {"t": rec.t}
    for ax in p.axes:
        for role in AXIS_ROLES[ax.kind]:
            out[column(ax.name, role)] = rec.signal(f"{ax.name}.{role}")
    for role, (row, _) in SPINDLE_SIGNALS.items():
        out[column("S", role)] = rec.signal(row)
    out["tool"] = np.asarray(rec.tool, dtype=np.float64)
    out["line"] = np.asarray(rec.line, dtype=np.float64)
    out["override"] = rec.override
    if truth:
        for row in TRUTH_ROWS:
            out[truth_column(row)] = rec.signal(row)
        out["true_vb"] = rec.vb
        out["true_part"] = np.asarray(rec.part, dtype=np.float64)
    return out


__all__ = [
    "AXIS_ROLES",
    "IDENTITIES",
    "SPINDLE_SIGNALS",
    "TRUTH_ROWS",
    "column",
    "columns",
    "description",
    "description_dict",
    "truth_column",
]
