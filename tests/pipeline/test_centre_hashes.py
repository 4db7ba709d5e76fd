"""A machining centre's worker pipeline at 500 Hz streams what it streamed before the
plant's cost cuts (issue 32 item 3): every channel, the events and the monitor's status,
hashed (``tests/_centre_hashes.py``) against the hashes the code before them wrote. A
difference fails naming each channel that changed."""

from __future__ import annotations

import json

import pytest
from _centre_hashes import HASHES, centre_hashes

pytestmark = pytest.mark.slow


def test_centre_pipeline_streams_what_it_streamed_before() -> None:
    want = json.loads(HASHES.read_text())
    got = centre_hashes()
    assert got["samples"] == want["samples"]
    changed = [
        f"{n}: {want['channels'].get(n)} -> {got['channels'].get(n)}"
        for n in sorted(set(want["channels"]) | set(got["channels"]))
        if want["channels"].get(n) != got["channels"].get(n)
    ]
    assert changed == []
    assert got["events"] == want["events"]
    assert want["events"]["count"] >= 1  # the run reaches past the teach-in: events raised
    assert got["status"] == want["status"]
