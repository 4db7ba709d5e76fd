"""The tool-life monitor's alarms as monitor events: wear near its limit, a short life.

The same two conditions the estimates message has always listed as ``alarms``
(:mod:`server.pipeline.estimates_out`): the estimated flank wear at
:data:`WEAR_ALARM_SHARE` of its limit (event ``wear_limit``, action ``alarm``) and the
estimated remaining life below :data:`LIFE_ALARM_MIN` minutes (event ``life_short``,
action ``notice``). A condition that holds for a tool raises its event once for that
tool, not on every block: :class:`WearAlarms` remembers, per kind, the tool (its
index: the count of tool changes) it has raised it for. After a restart from a
checkpoint the memory is empty: a condition still true is raised once more, which
tells whoever looks now.

Only the estimates are used (never the simulator's true wear).
"""

from __future__ import annotations

import math
from typing import TypedDict

from common.event_kinds import EventKind
from server.records.monitor_events import DEFAULT_ACTIONS, MonitorEvent

#: wear alarms: the estimated flank wear at this share of its limit, remaining life below
WEAR_ALARM_SHARE = 0.9
LIFE_ALARM_MIN = 2.0


class BlockIds(TypedDict, total=False):
    """The CNC's identities of a block (a key missing: not known)."""

    tool: int
    program: str
    line: int
    part: int


def wear_alarm_message(tool: object, vb_est: float, vb_limit: float) -> str:
    """The wear alarm in an operator's words: the tool, its wear, its share of the one
    limit, and the alarm's threshold as what it is (a share of that limit)."""
    who = f"tool {tool}: " if isinstance(tool, int) and tool > 0 else ""
    return (
        f"{who}flank wear {vb_est:.3f} mm, {100 * vb_est / vb_limit:.0f} % of its limit "
        f"{vb_limit:.3f} mm (alarm at {100 * WEAR_ALARM_SHARE:.0f} %): change the tool"
    )


class WearAlarms:
    """Raise ``wear_limit`` and ``life_short`` once per tool (see the module docstring)."""

    def __init__(self) -> None:
        #: kind -> the tool index it was raised for
        self._raised: dict[str, int] = {}

    def check(
        self,
        t: float,
        tool_index: int,
        vb_est: float,
        vb_limit: float,
        life_left: float,
        ids: BlockIds,
    ) -> list[MonitorEvent]:
        """The events the wear estimate at ``t`` raises for the tool ``tool_index``
        (0 for the first tool, +1 at each change); ``ids``: the CNC's ``tool``,
        ``program``, ``line``, ``part`` of the block (missing keys: not known)."""
        out: list[MonitorEvent] = []
        if math.isfinite(vb_est) and math.isfinite(vb_limit) and vb_limit > 0:
            if vb_est >= WEAR_ALARM_SHARE * vb_limit:
                msg = wear_alarm_message(ids.get("tool", 0), vb_est, vb_limit)
                out += self._raise("wear_limit", t, tool_index, vb_est, WEAR_ALARM_SHARE * vb_limit,
                                   "mm", msg, ids)  # fmt: skip
        if math.isfinite(life_left) and life_left < LIFE_ALARM_MIN:
            msg = f"remaining tool life {life_left:.1f} min (below {LIFE_ALARM_MIN:g} min)"
            out += self._raise("life_short", t, tool_index, life_left, LIFE_ALARM_MIN, "min",
                               msg, ids)  # fmt: skip
        return out

    def _raise(
        self,
        kind: str,
        t: float,
        tool_index: int,
        value: float,
        limit: float,
        unit: str,
        message: str,
        ids: BlockIds,
    ) -> list[MonitorEvent]:
        if self._raised.get(kind) == tool_index:
            return []
        self._raised[kind] = tool_index
        tool, line, part = ids.get("tool", 0), ids.get("line", 0), ids.get("part", -1)
        return [
            MonitorEvent(
                kind=EventKind(kind),
                action=DEFAULT_ACTIONS[EventKind(kind)],
                t=t,
                tool=int(tool) if isinstance(tool, int | float) else 0,
                program=str(ids.get("program", "") or ""),
                line=int(line) if isinstance(line, int | float) else 0,
                part=int(part) if isinstance(part, int | float) else -1,
                value=value,
                limit=limit,
                unit=unit,
                message=message,
            )
        ]
