"""Tool wear as a live part: seed 004's wearing tool on the simulated stage, its monitor fed
by the adaptive observer, its alarms, the tool changed at the flank-wear limit.

:class:`WearPart` drives :class:`~server.pipeline.wear_passes.ToolWearPasses`: before each
block it starts the pass under way (the wear model advanced over it, so the stage cuts
with the pass's own wear force: :meth:`WearPart.force_gain` is that force over the sharp
tool's); after the stage's observers it feeds the life monitor the adaptive observer's
force, raises the alarms (:mod:`server.pipeline.wear_alarms`: once per tool) and changes
the tool at the flank-wear limit (the CNC knows a tool change: a disturbance of the cut;
the worn tool's life goes to the history).

It simulates the tool's wear beside the machine, so it runs on the simulator only. Its
share of the status strip: its own tool (numbered 1, 2, ... as the run changes it), the
estimated wear as a share of the one flank-wear limit :data:`VB_LIMIT` (the alarm at
:data:`~server.pipeline.wear_alarms.WEAR_ALARM_SHARE` of it), the remaining life, and
:data:`WEAR_OF`, the words that say the tool is not the part program's (issue 28: the
default scenario's milling machine, with its tools T1/T2, is another machine). Its alarms
and tool lives name this tool, never the milling machine's tool, program, line or part.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from common.errors import ParameterError
from harness.wear_clock import AcceleratedToolWear
from server.pipeline.estimates_out import StatusStrip
from server.pipeline.machine_view import MachineView
from server.pipeline.part import (
    Block,
    Channel,
    Chart,
    LivePart,
    Notice,
    Outputs,
    Plan,
    Verdict,
    needs_simulator,
)
from server.pipeline.stage_part import COLORS
from server.pipeline.wear_alarms import WEAR_ALARM_SHARE, WearAlarms
from server.pipeline.wear_passes import VB_LIMIT, PassState, ToolWearPasses
from server.records.history.store import ToolChange

__all__ = ["WEAR", "WEAR_OF", "WearPart", "WearPartState"]

#: whose tool the wear part's is, in the status strip's words (a tool beside the spindle's)
WEAR_OF = "the stage's turning tool (seed 004's wear law)"

WEAR = Chart(
    "wear",
    "Tool wear: true vs estimated, tool-life line, remaining life",
    page="operator",
    order=20,
    window_s=120.0,
)


@dataclass
class WearPartState:
    """The tool: its pass under way and the wear model with its life monitor. (The
    alarms' memory is not kept: after a restart a condition still true is raised once
    more, :mod:`server.pipeline.wear_alarms`.)"""

    passes: PassState
    wear: AcceleratedToolWear


class WearPart(LivePart):
    """The wearing tool (module docstring).

    Parameters
    ----------
    wear_rate
        Minutes of wear per second of machining for the first tool (knob ``wear_rate``).
    """

    name = "wear"
    needs = ("stage",)
    charts = (WEAR,)
    channels = WEAR.series(
        Channel(
            "vb_true",
            "mm",
            "flank wear, true",
            "wear",
            truth=True,
            color=COLORS["true"],
            legend="VB true [mm]",
        ),
        Channel(
            "vb_est",
            "mm",
            "flank wear, estimated from the adaptive observer",
            "wear",
            color=COLORS["adaptive"],
            legend="VB estimated [mm]",
        ),
        Channel(
            "vb_limit",
            "mm",
            "flank-wear limit (tool change)",
            "wear",
            color=COLORS["switching"],
            legend="limit",
        ),
        Channel(
            "life_left",
            "min",
            "remaining tool life (wear clock)",
            "wear",
            color=COLORS["dfo"],
            axis="life",
            legend="life left [min]",
        ),
    )

    def __init__(self, wear_rate: float) -> None:
        self.tool = ToolWearPasses(wear_rate)
        self.alarms = WearAlarms()
        self._changes: list[ToolChange] = []

    def requires(self, machine: MachineView) -> Verdict:
        return needs_simulator(machine, "the tool's wear (seed 004's model sets the force)")

    def before(self, plan: Plan) -> None:
        self.tool.begin(plan.t0, float(plan.knobs["wear_rate"]))

    def force_gain(self, t: float) -> float:
        return self.tool.gain(t)

    def step(self, block: Block) -> Outputs:
        tool = self.tool
        if block.discontinuity is not None:  # a wear pass under way spans the gap
            tool.interrupt()
        f_ad = block.outputs["f_adaptive"]
        worn = tool.accumulate(block.n, f_ad, block.plant.nominal_force, block.sample_time)
        s = tool.state
        # the alarms before a change resets the estimate
        events = self.alarms.check(
            float(block.meas.t[-1]),
            s.tools_changed,
            s.vb_est,
            VB_LIMIT,
            s.life_left,
            {"tool": self.tool_number},
        )
        if worn:
            self._new_tool(block)
        s = tool.state
        return {
            "vb_true": block.held(s.vb_true),
            "vb_est": block.held(s.vb_est),
            "vb_limit": block.held(VB_LIMIT),
            "life_left": block.held(s.life_left),
        }, events

    def _new_tool(self, block: Block) -> None:
        """A sharp tool at the flank-wear limit; the CNC knows a tool change: the force's
        DC steps back to the sharp tool's. The worn tool's life is recorded."""
        self._changes.append(self._life(block, "wear_limit"))
        self.tool.new_tool(float(block.knobs["wear_rate"]))
        self.tool.state.tool_start_t = block.t_end
        block.notice(Notice("disturbance", block.t_end))

    def _life(self, block: Block, cause: str) -> ToolChange:
        """The life of the wearing tool, ending now: its number (:attr:`tool_number`:
        this part's own tool, never the part program's tool in the spindle), its index
        (the same: 1 for the first tool of the run), the source times it was mounted and
        changed, the estimated flank wear at the change (None before the first
        estimate), the simulator's true wear (None without truth) and the cause."""
        st = self.tool.state
        index = self.tool_number
        truth = block.has_truth
        return {
            "tool": index,
            "index": index,
            "start_t": st.tool_start_t,
            "end_t": block.t_end,
            "wear_at_change_mm": st.vb_est if math.isfinite(st.vb_est) else None,
            "wear_true_mm": st.vb_true if truth else None,
            "wear_true_share": st.vb_true / VB_LIMIT if truth else None,
            "cause": cause,
        }

    @property
    def tools_changed(self) -> int:
        return self.tool.state.tools_changed

    @property
    def tool_number(self) -> int:
        """The wearing tool's number: 1 for the first tool of the run, +1 at each change."""
        return self.tool.state.tools_changed + 1

    def status(self) -> StatusStrip:
        """The strip's wear fields, all of this part's one tool (module docstring)."""
        s = self.tool.state
        share = s.vb_est / VB_LIMIT if math.isfinite(s.vb_est) else math.nan
        return {
            "wear_share": share,
            "life_left_min": s.life_left,
            "wear_tool": self.tool_number,
            "wear_of": WEAR_OF,
            "wear_limit_mm": VB_LIMIT,
            "wear_alarm_share": WEAR_ALARM_SHARE,
        }

    def take_tool_changes(self) -> list[ToolChange]:
        out, self._changes = self._changes, []
        return out

    def state(self) -> WearPartState:
        return WearPartState(self.tool.state, self.tool.wear)

    def restore(self, state: object) -> None:
        if not isinstance(state, WearPartState):
            raise ParameterError("state.parts.wear", "a WearPartState", type(state).__name__)
        self.tool.state, self.tool.wear = state.passes, state.wear
        self.tool.f_sharp = self.tool.wear.model.force(np.zeros(3), self.tool.wear.feed)
