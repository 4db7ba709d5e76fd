"""The live pipeline streams what it streamed before the refactor into parts (issue 26).

Fixed-seed runs (``tests/_hashes.py``, each naming its scenario: the seeds' scenario
``default`` (the live default before issue 31, now the machining centre) with knob
changes, injections and a checkpoint round trip; the two seed scenarios; a replayed log)
hashed channel by
channel, with their events and tool changes, against the hashes the code before the
refactor wrote (``tests/pipeline/channel_hashes.json``). A difference fails with every
channel named, unless it is one of :data:`EXPECTED`, each with its reason.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from _hashes import HASHES, RUNS, compare, run_hashes

pytestmark = pytest.mark.slow

#: the channels of the parts a scenario does not run: streamed before as placeholders
#: (NaN, or the wear's 0 / 0.3 mm), not streamed now (a pipeline streams its parts')
_NOT_RUN = {
    "eccentricity (seed 003's milling tool: the default scenario's)": (
        "ecc_a_cancel ecc_a_m ecc_cost ecc_esc_on ecc_f1x ecc_fast_on ecc_identifying "
        "ecc_mass_err ecc_theta_cancel ecc_theta_m ecc_true_deg ecc_true_um"
    ),
    "process (the part program and its monitor: the default scenario's)": (
        "mon_event_true mon_extreme mon_f mon_line mon_lower mon_mean mon_override mon_part "
        "mon_pattern mon_pattern_limit mon_state mon_suspected mon_tool mon_upper"
    ),
    "wear (seed 004's wearing tool: the default scenario's)": "life_left vb_est vb_limit vb_true",
}
#: run -> the differences expected, each a line of :func:`_hashes.compare`, with the reason
EXPECTED: dict[str, dict[str, str]] = {
    run: {
        f"channel {name}: gone": f"the {part.split(' ')[0]} part does not run here: {part}"
        for part, names in _NOT_RUN.items()
        for name in names.split()
    }
    for run in ("seed000-weight-0", "seed001-spindle-0", "replay-0")
}
# issue 28: the wear part's tool lives are numbered by its own tool (1, 2, ...), no longer
# by the milling machine's tool in the spindle at the change; the channels are the same
# issue 32: the process part tells the monitor which blocks can cut (the program's air moves
# are watched for collisions only, not taught), so its band differs there; every other
# channel and the events are as before
_AIR_MOVES = "the monitor told which blocks cannot cut (issue 32): air moves not taught"
# issue 32 (rates line): the breakage confirmation is 1/8 of a revolution (25 samples at the
# default program's 1,500 rpm at 5 kHz), no longer 3 samples: the same 4 events, the two
# breakage alarms 3.6 ms and 5.8 ms later (the second, in the injected collision's block,
# now after the collision's alarm, not before it), so the monitor's state channel too
_CONFIRM = "breakage confirmed over 1/8 revolution, not 3 samples (issue 32): alarms later"
EXPECTED["default-0"] = {
    "tool_changes: {'count': 11, 'hash': '3780e85cd13920da'} -> "
    "{'count': 11, 'hash': '2b19aa2d44d4b8e8'}": "the wear part's tools numbered by its own "
    "count, not by the milling machine's tool (issue 28)",
    "channel mon_lower: de8fd11fab424493 -> 8fc00f1ba8f4849a": _AIR_MOVES,
    "channel mon_upper: 3889c5f9ec332947 -> 3955289cea2b3b89": _AIR_MOVES,
    "events: {'count': 4, 'hash': '81222ab60ed6e655'} -> "
    "{'count': 4, 'hash': '835601219dc40e6d'}": _CONFIRM,
    "channel mon_state: 2699fd2061f78e1a -> 156d8960963df2f8": _CONFIRM,
}


@pytest.mark.parametrize("name", list(RUNS))
def test_channels_identical_to_before_the_parts(name: str, tmp_path: Path) -> None:
    want = json.loads(HASHES.read_text())[name]
    got = run_hashes(RUNS[name], tmp_path)
    diff = compare(want, got)
    expected = EXPECTED.get(name, {})
    assert [d for d in diff if d not in expected] == []
    assert sorted(diff) == sorted(expected)  # each expected difference is really there


def test_every_run_names_a_seeds_scenario() -> None:
    # issue 31: the live default became the machining centre; the hashes are the seeds'
    # scenarios', each run by its name, never by the default
    from server.pipeline.scenarios import DEFAULT_SCENARIO, SCENARIOS

    for name, run in RUNS.items():
        assert run.replay or (run.scenario in SCENARIOS and run.scenario != DEFAULT_SCENARIO), name
    assert {r.scenario for r in RUNS.values() if not r.replay} == {
        "default",
        "seed000-weight",
        "seed001-spindle",
    }
