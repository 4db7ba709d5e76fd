"""The kinds of monitor events, defined once (the simulator, the detectors, the service).

A process event happens in the cut and is what the simulator injects and the process
monitor's detectors look for (:class:`ProcessEventKind`); the tool-life monitor adds its
own two. Every event the service keeps, streams and publishes is one of
:class:`EventKind`. Both are ``StrEnum``: a member is its string (``EventKind.BREAKAGE ==
"breakage"``), so it is written to JSON, a database and the broker as that string and a
string read back compares equal; a misspelt member fails at import, not at run time.

The process kinds are listed first and in this order in both enumerations: the detectors'
ids in the monitor's kernel and the simulator's event codes index them.
"""

from __future__ import annotations

from enum import StrEnum


class ProcessEventKind(StrEnum):
    """What happens in the cut: injected by the simulator, found by the detectors."""

    #: a tooth broken or chipped (the chip load moves to the next tooth)
    BREAKAGE = "breakage"
    #: a collision or an overload (the force far above what was taught)
    COLLISION = "collision"
    #: no tool, or no cut where the program cuts (the force far below it)
    MISSING_TOOL = "missing_tool"


class EventKind(StrEnum):
    """What raised a monitor event: a process detector or the tool-life monitor."""

    BREAKAGE = ProcessEventKind.BREAKAGE.value
    COLLISION = ProcessEventKind.COLLISION.value
    MISSING_TOOL = ProcessEventKind.MISSING_TOOL.value
    #: the estimated flank wear near its limit
    WEAR_LIMIT = "wear_limit"
    #: the remaining tool life short
    LIFE_SHORT = "life_short"


#: the process kinds as monitor events, in the detectors' order
PROCESS_EVENTS: tuple[EventKind, ...] = tuple(EventKind(k.value) for k in ProcessEventKind)


__all__ = ["PROCESS_EVENTS", "EventKind", "ProcessEventKind"]
