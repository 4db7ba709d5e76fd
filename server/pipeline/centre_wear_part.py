"""Wear per tool on a machine with a spindle's power: issue 31 item 2, issue 35 item 7 live.

:class:`CentreWearPart` reads the spindle part's cutting power (``spindle_cut``: the
power less the idle taught in the air, NaN while the speed changes) and the CNC's
identities (``tool``, ``line``, ``override``), cuts it into block executions (a change
of the CNC's line starts one, as the process monitor does) and hands each execution's
mean cutting power and its seconds of known power to
:class:`estimators.wear.centre.CentreWear`: the power relative to the taught fresh-tool
value of the same (tool, program, block), seed 004's monotone state per tool, a 95 %
interval. The map from that relative power to VB is the machine's own: a prior
("uncalibrated", its wide interval) until a VB measured at a tool change is entered
(:meth:`CentreWearPart.label`, ``POST /api/tool-lives/vb``), then refitted from the
labelled lives of that tool ("calibrated"). A lathe's map is never carried here.

Its channels (chart ``centre-wear``, operator page): the VB of the tool in the spindle
with its band and the stated limit; its share of the status strip: the tool in the
spindle (``wear_tool``), its VB as a share of the limit (``wear_share``) with the
interval's shares (``wear_lo_share``, ``wear_hi_share``), whether the map is calibrated
(``wear_calibrated``), and the life left [min of machine time at the tool's duty so
far]. A new instance detected (the reading falls back to a fresh tool's) ends a life:
:meth:`take_tool_changes` gives it to the history (cause ``wear_limit`` when the
estimate was at 90 % of the limit or more, else ``unknown``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TypedDict

import numpy as np

from common.errors import ParameterError
from estimators.wear.centre import CentreWear, CentreWearParams, CentreWearState
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
    needs_signals,
)
from server.records.history.store import ToolChange

__all__ = ["CENTRE_WEAR", "CentreWearPart", "CentreWearPartState"]

CENTRE_WEAR = Chart(
    "centre-wear",
    "Tool wear of the spindle's tool: flank wear from the cutting power relative to the "
    "taught fresh tool (95 % band; uncalibrated until a VB measured at a tool change is in)",
    page="operator",
    order=7,
    window_s=600.0,
)
#: a life ended at this share of the limit or more was ended by the wear
_WORN_SHARE = 0.9


class WearLabel(TypedDict):
    """A VB measured at a tool's change, as :meth:`CentreWearPart.label` took it: the
    tool, its life's index and end [s], the VB measured and the estimate then [mm], and
    whether the tool's wear map is calibrated by its labels now."""

    tool: int
    index: int
    end_t: float
    vb_mm: float
    vb_est_mm: float
    calibrated: bool


class WearLife(TypedDict):
    """A life the part ended (:meth:`CentreWearPart.lives`): VB measured None when not
    labelled."""

    tool: int
    index: int
    end_t: float
    vb_est_mm: float
    vb_mm: float | None


@dataclass
class CentreWearPartState:
    """The estimator's state and the execution under way (its sums)."""

    est: CentreWearState
    line: int = 0
    tool: int = 0
    sum_w: float = 0.0
    n: int = 0
    override: float = 1.0
    t: float = 0.0
    changes: list[ToolChange] = field(default_factory=list)


class CentreWearPart(LivePart):
    """Each tool's flank wear from the spindle's cutting power (module docstring)."""

    name = "centre_wear"
    needs = ("spindle",)
    charts = (CENTRE_WEAR,)
    channels = CENTRE_WEAR.series(
        Channel(
            "tool_vb",
            "mm",
            "flank wear of the spindle's tool, estimated from its cutting power",
            "wear",
            color="#d55e00",
            width=2.0,
            interval=("tool_vb_lo", "tool_vb_hi", "tool_vb_taught"),
            legend="VB estimated [mm]",
        ),
        Channel("tool_vb_lo", "mm", "lower end of the 95 % interval", "wear", legend="95 % low"),
        Channel("tool_vb_hi", "mm", "upper end of the 95 % interval", "wear", legend="95 % high"),
        Channel(
            "tool_vb_taught",
            "1",
            "1 once the tool's blocks have their taught fresh-tool reference",
            "wear",
        ),
        Channel(
            "tool_vb_limit",
            "mm",
            "the stated flank-wear limit",
            "wear",
            color="#7b3294",
            dash=(8.0, 5.0),
            legend="limit [mm]",
        ),
    )

    def __init__(self, program: str = "", params: CentreWearParams | None = None) -> None:
        self.program = program
        self.wear = CentreWear(params)
        self.st = CentreWearPartState(self.wear.initial_state())

    def requires(self, machine: MachineView) -> Verdict:
        return needs_signals(
            machine, "spindle.speed", "spindle.power", what="the spindle's cutting power"
        )

    # ------------------------------------------------------------------ step
    def step(self, block: Block) -> Outputs:
        n = block.n
        cut = np.asarray(column_or(block.outputs, "spindle_cut", n, math.nan), dtype=np.float64)
        cols = block.source.columns or {}
        line = np.asarray(column_or(cols, "line", n, 0.0), dtype=np.float64)
        tool = np.asarray(column_or(cols, "tool", n, 0.0), dtype=np.float64)
        ovr = np.asarray(column_or(cols, "override", n, 1.0), dtype=np.float64)
        t = np.asarray(block.t, dtype=np.float64)
        dt = float(t[1] - t[0]) if n > 1 else 0.0
        cuts = np.flatnonzero(line[1:] != line[:-1]) + 1
        for a, b in zip([0, *cuts], [*cuts, n], strict=True):
            if n == 0:
                break
            ln, tl = int(line[a]), int(tool[a])
            if ln != self.st.line or tl != self.st.tool:
                self._close(dt)
                self.st.line, self.st.tool = ln, tl
                self.st.override = float(ovr[a]) if math.isfinite(ovr[a]) else math.nan
            seg = cut[a:b]
            ok = np.isfinite(seg)
            self.st.sum_w += float(seg[ok].sum())
            self.st.n += int(ok.sum())
            self.st.t = float(t[b - 1])
        e = self.wear.estimate(self.st.est, self.st.tool) if self.st.tool else None
        mm = 1e3
        vb = e["vb"] if e else math.nan
        return {
            "tool_vb": block.held(float(vb) * mm),
            "tool_vb_lo": block.held(float(e["lo"]) * mm if e else math.nan),
            "tool_vb_hi": block.held(float(e["hi"]) * mm if e else math.nan),
            "tool_vb_taught": block.held(float(self._taught(self.st.tool))),
            "tool_vb_limit": block.held(self.wear.params.vb_limit * mm),
        }, []

    def _close(self, dt: float) -> None:
        """The execution under way ended: one reading (a cut block) or nothing."""
        s = self.st
        if s.tool > 0 and s.n > 0:
            key = (s.tool, self.program, s.line)
            before = len(s.est.lives)
            s.est, _ = self.wear.observe(s.est, key, s.sum_w / s.n, s.n * dt, s.t, s.override)
            for life in s.est.lives[before:]:
                share = life.vb_est / self.wear.params.vb_limit
                s.changes.append({
                    "tool": life.tool,
                    "index": life.instance,
                    "start_t": life.start_t,
                    "end_t": life.end_t,
                    "wear_at_change_mm": life.vb_est * 1e3,
                    "cause": "wear_limit" if share >= _WORN_SHARE else "unknown",
                })  # fmt: skip
        s.sum_w, s.n = 0.0, 0

    def _taught(self, tool: int) -> bool:
        """A cut block of ``tool`` has its taught fresh-tool reference."""
        return any(k[0] == tool and self.wear._is_cut(b) for k, b in self.st.est.blocks.items())

    # ------------------------------------------------------------------ labels
    def label(self, tool: int, vb_mm: float) -> WearLabel:
        """A VB measured [mm] at ``tool``'s latest unlabelled tool change (REST).

        Raises
        ------
        ParameterError
            ``tool`` with no such change, ``vb_mm`` out of range (the estimator's words,
            in mm).
        """
        if not (isinstance(vb_mm, int | float) and math.isfinite(vb_mm)):
            raise ParameterError("vb_mm", "a flank wear in mm", vb_mm)
        lim = 3 * self.wear.params.vb_limit * 1e3
        if not 0 < vb_mm <= lim:
            raise ParameterError("vb_mm", f"a flank wear in (0, {lim:g}] mm", vb_mm)
        life = self.wear.label(self.st.est, int(tool), float(vb_mm) * 1e-3)
        return {
            "tool": life.tool,
            "index": life.instance,
            "end_t": life.end_t,
            "vb_mm": float(vb_mm),
            "vb_est_mm": life.vb_est * 1e3,
            "calibrated": self.wear.calibrated(self.st.est, life.tool),
        }

    def lives(self) -> list[WearLife]:
        """The lives this part ended, labelled or not."""
        return [
            {"tool": lf.tool, "index": lf.instance, "end_t": lf.end_t,
             "vb_est_mm": lf.vb_est * 1e3,
             "vb_mm": lf.labelled * 1e3 if math.isfinite(lf.labelled) else None}
            for lf in self.st.est.lives
        ]  # fmt: skip

    # ------------------------------------------------------------------ status
    def status(self) -> StatusStrip:
        """The strip's wear fields, of the tool in the spindle."""
        tool = self.st.tool
        lim = self.wear.params.vb_limit
        if tool <= 0:
            return {}
        e = self.wear.estimate(self.st.est, tool)
        tf = self.st.est.tools.get(tool)
        life_min = math.nan
        if tf is not None and math.isfinite(float(e["life_s"])):
            up = self.st.t - tf.mount_t
            duty = tf.cut_s / up if up > 0 else 0.0
            life_min = float(e["life_s"]) / duty / 60.0 if duty > 0 else math.nan
        return {
            "wear_tool": tool,
            "wear_of": "",
            "wear_share": float(e["vb"]) / lim,
            "wear_lo_share": float(e["lo"]) / lim,
            "wear_hi_share": float(e["hi"]) / lim,
            "wear_calibrated": bool(e["calibrated"]),
            "wear_limit_mm": lim * 1e3,
            "life_left_min": life_min,
        }

    def take_tool_changes(self) -> list[ToolChange]:
        out, self.st.changes = self.st.changes, []
        return out

    def state(self) -> CentreWearPartState:
        return self.st

    def restore(self, state: object) -> None:
        if not isinstance(state, CentreWearPartState):
            raise ParameterError(
                "state.parts.centre_wear", "a CentreWearPartState", type(state).__name__
            )
        self.st = state
