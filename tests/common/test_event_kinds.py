"""The event kinds: one definition (common/event_kinds.py), its members written as strings."""

from __future__ import annotations

import json

import pytest

from common.event_kinds import PROCESS_EVENTS, EventKind, ProcessEventKind


def test_the_process_kinds_lead_the_event_kinds_in_the_same_order() -> None:
    # the detectors' ids and the simulator's codes index the process kinds
    values = [k.value for k in EventKind]
    assert values[: len(ProcessEventKind)] == [k.value for k in ProcessEventKind]
    assert [k.value for k in PROCESS_EVENTS] == [k.value for k in ProcessEventKind]
    assert all(isinstance(k, EventKind) for k in PROCESS_EVENTS)
    assert len(set(values)) == len(values) == 5


def test_a_member_is_its_string_on_every_wire() -> None:
    assert EventKind.WEAR_LIMIT == "wear_limit" and f"{EventKind.WEAR_LIMIT}" == "wear_limit"
    assert json.dumps({EventKind.BREAKAGE: ProcessEventKind.COLLISION}) == (
        '{"breakage": "collision"}'
    )
    assert EventKind("missing_tool") is EventKind.MISSING_TOOL
    assert {"breakage": 1}[ProcessEventKind.BREAKAGE] == 1


def test_an_unknown_kind_is_refused_by_name() -> None:
    with pytest.raises(ValueError, match="'breakge' is not a valid EventKind"):
        EventKind("breakge")
