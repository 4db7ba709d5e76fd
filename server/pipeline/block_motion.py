"""What the CNC says of a block: may it cut (the process monitors' ``cutting=``).

A process monitor taught per (tool, program, block) judges a block that cannot cut (a G0
rapid, a tool change, a spindle start or stop, a dwell, a feed along the tool's axis
alone) by the collision's extreme limit only: a signal's error floor there (an axis
accelerating, a spindle running up) would otherwise be taught as a cut and its next
execution judged against it (:mod:`estimators.monitoring.process`, ``step(...,
cutting=False)``; issue 32: 37 -> 1 false alarms in the reproduction's quick rows). The
live parts ask :class:`CanCut`, which answers from the best the source says:

``program``
    The part program's text is known (the simulated machining centre,
    :class:`server.pipeline.centre_source.CentreSource`): per G-code line, a G1 feed in
    the XY plane (Z held) may cut; everything else cannot (:func:`cutting_lines`, as the
    reproduction reads it).
``commanded feed``
    The feed carries each axis' commanded position (``q_cmd``) but not the program's
    text (a broker's drive blocks, a CNC's export, OPC UA): a block execution may cut
    while the commanded path has moved in the plane and not along the tool's axis (Z)
    since the block began, and the spindle's commanded speed (where given) is not 0. A
    dwell, a tool change and a spindle start (no commanded motion), a plunge or a
    retract (Z moves) cannot. What the commanded feed does not say: a G0 rapid in the
    plane (at the clearance) reads as a feed, since the machine's rapid rate is not in
    its description; there the monitor is as before the fix (taught per block: in the
    air a rapid's taught mean is under ``min_cut_force``, so its missing-tool and
    breakage detectors do not watch it).
``not said``
    Neither (no commanded position: a log of efforts and positions only): every block
    may cut, the monitor's default.

Without the CNC's line (no block executions) the commanded feed judges each call's
samples alone.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from common.machine_description import MachineDescription
from server.pipeline.part import diff_from

if TYPE_CHECKING:
    from common.arrays import F64

__all__ = ["FROM_FEED", "FROM_PROGRAM", "NOT_SAID", "CanCut", "cutting_lines", "program_lines"]

FROM_PROGRAM = "program"
FROM_FEED = "commanded feed"
NOT_SAID = "not said"
#: commanded travel within a block execution below which an axis has not moved [m]
#: (a commanded position is the interpolator's, not a measurement: held, it is constant)
HELD_M = 1e-6
#: the tool's axis: a feed along it alone is a plunge or a retract, not a cut in the plane
TOOL_AXIS = "Z"


def cutting_lines(program: Any) -> dict[int, bool]:
    """Per G-code line, whether the CNC's program lets the block cut: a G1 feed in the
    XY plane (Z held; the machining centre's programs cut only so,
    :class:`machine.centre.program.Program`). A G0 rapid, a tool change, a spindle start,
    a dwell, the end and a feed along Z alone (a plunge into the clearance) cannot: the
    monitors judge them by the collision's extreme limit only (as an industrial monitor
    is switched on only around the program's cuts). Read from the program's text, not
    from its cuts (the truth)."""
    out: dict[int, bool] = {}
    for b, _tool, _rpm, pos in program.walk():
        out[b.line] = bool(
            b.kind == "feed"
            and b.target is not None
            and abs(b.target[2] - pos[2]) <= 1e-12
            and math.hypot(b.target[0] - pos[0], b.target[1] - pos[1]) > 0.0
        )
    return out


def program_lines(source: object) -> dict[int, bool] | None:
    """:func:`cutting_lines` of the program a source runs, where it holds the program's
    text (the simulated machining centre: ``source.machine.program``); else None."""
    program = getattr(getattr(source, "machine", None), "program", None)
    if program is None or not hasattr(program, "walk"):
        return None
    return cutting_lines(program)


class CanCut:
    """Per block execution, whether the CNC lets it cut (module docstring).

    Parameters
    ----------
    description
        The machine's description: the axes' ``q_cmd`` columns, the spindle's
        ``speed_cmd``.
    lines
        Per G-code line from the program's text (:func:`cutting_lines`), if known.
    """

    def __init__(
        self, description: MachineDescription, lines: Mapping[int, bool] | None = None
    ) -> None:
        self.lines = dict(lines) if lines is not None else None
        self._cmd: dict[str, str] = {
            a.name: a.signals["q_cmd"] for a in description.axes if "q_cmd" in a.signals
        }
        sp = description.spindle
        self._speed_cmd = (sp.signals if sp is not None else {}).get("speed_cmd", "")
        # without the CNC's line a block execution is not known: each call is judged alone
        self._per_block = "line" in description.identities
        self.source = FROM_PROGRAM if self.lines is not None else (
            FROM_FEED if self._cmd else NOT_SAID
        )  # fmt: skip
        self._last: dict[str, float] = {}  # each axis' last commanded position
        self._plane = 0.0  # commanded travel in the plane since the block began [m]
        self._tool = 0.0  # ... along the tool's axis [m]
        self._stopped = False  # the spindle's command was 0 in the block

    def __call__(self, cols: Mapping[str, F64], line: int, a: int, b: int, new: bool) -> bool:
        """May the samples ``a:b`` of ``cols`` (one execution of ``line``; ``new``: its
        first samples) cut?"""
        if self.lines is not None:
            return self.lines.get(int(line), True)
        if not self._cmd:
            return True
        if new or not self._per_block:
            self._plane = self._tool = 0.0
            self._stopped = False
            self._last.clear()  # the block's first sample starts its travel
        for ax, col in self._cmd.items():
            if col not in cols:
                continue
            q = np.asarray(cols[col][a:b], dtype=np.float64)
            if not q.size:
                continue
            prev = self._last.get(ax, float(q[0]))
            d = float(np.nansum(np.abs(diff_from(q, prev))))
            if math.isfinite(q[-1]):
                self._last[ax] = float(q[-1])
            if ax == TOOL_AXIS:
                self._tool += d
            else:
                self._plane += d
        if self._speed_cmd in cols:
            s = np.asarray(cols[self._speed_cmd][a:b], dtype=np.float64)
            self._stopped |= bool(np.any(s == 0.0))
        return self._plane > HELD_M and self._tool <= HELD_M and not self._stopped
