"""The live pipeline streams what it streamed before the refactor into parts (issue 26).

Fixed-seed runs (``tests/_hashes.py``: the default scenario with knob changes, injections
and a checkpoint round trip; the two seed scenarios; a replayed log) hashed channel by
channel, with their events and tool changes, against the hashes the code before the
refactor wrote (``tests/pipeline/channel_hashes.json``). A difference fails with every
channel named.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from _hashes import HASHES, RUNS, compare, run_hashes

pytestmark = pytest.mark.slow


@pytest.mark.parametrize("name", list(RUNS))
def test_channels_identical_to_before_the_parts(name: str, tmp_path: Path) -> None:
    want = json.loads(HASHES.read_text())[name]
    got = run_hashes(RUNS[name], tmp_path)
    assert compare(want, got) == []
