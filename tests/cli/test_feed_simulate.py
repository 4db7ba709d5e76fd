"""``cutwatch feed --simulate`` through a real Mosquitto: simulated machining centres
published as their edge devices would (issue 31, item 4)."""

from __future__ import annotations

import time

import numpy as np
import pytest
from _broker import broker
from test_feed import collect, subscriber

from machine.centre.program import program_variant
from server.cli.main import main
from server.pipeline.centre_feed import CentreFeed, CentreFeedParams
from server.records.drive_wire import check_block, decode_drive, decode_meta, machine_of


def _received(
    port: int, argv: list[str], topics: list[str], blocks: int
) -> list[tuple[str, bytes, bool]]:
    """What a subscriber to ``topics`` receives from a feed of ``blocks`` drive blocks."""
    c, got = subscriber(port, topics)
    try:
        assert main(["feed", "--simulate", *argv, "--broker", f"mqtt://127.0.0.1:{port}",
                     "--quiet"]) == 0  # fmt: skip
        return collect(got, lambda msgs: sum(t.endswith("/drive") for t, _, _ in msgs) >= blocks)
    finally:
        c.loop_stop()
        c.disconnect()


def test_three_machines_each_with_its_own_program_seed_and_trace() -> None:
    argv = ["--machine", "vmc", "--machines", "3", "--rate", "1000", "--seconds", "3",
            "--speed", "0", "--seed", "7"]  # fmt: skip
    with broker() as port:
        msgs = _received(port, argv, ["cutwatch/+/#"], 3 * 60)
    names = ["vmc-1", "vmc-2", "vmc-3"]
    for k, name in enumerate(names):
        (meta,) = [decode_meta(p) for t, p, _ in msgs if t == f"cutwatch/{name}/meta"]
        machine = machine_of(meta)
        assert machine.sample_time == 1e-3 and machine.axis_names == ("X", "Y", "Z")
        assert machine.axis("X").kind == "two_inertia" and machine.spindle is not None
        blocks = [decode_drive(p) for t, p, _ in msgs if t == f"cutwatch/{name}/drive"]
        assert [b.seq for b in blocks] == list(range(60))  # 3 s in 50 ms blocks
        assert all(b.n == 50 for b in blocks)
        assert all(check_block(b, machine).ignored == () for b in blocks)
        assert {b.program for b in blocks} == {program_variant(k).name}
        # the same machine simulated here gives the same samples (float32 efforts)
        feed = CentreFeed(k, 7 + k, CentreFeedParams(rate_hz=1000.0))
        ref = [decode_drive(feed.next_block(i)) for i in range(60)]
        for col in ("X_q_l", "S_speed", "Z_i_m"):
            got = np.concatenate([b.columns[col] for b in blocks])
            want = np.concatenate([b.columns[col] for b in ref])
            np.testing.assert_array_equal(got, want)
        tools = np.concatenate([b.identities()["tool"] for b in blocks])  # type: ignore[index]
        assert tools[0] == 0 and tools[-1] == 1  # T1 mounted by the first tool change (2 s)
    z = [np.concatenate([decode_drive(p).columns["Z_i_m"] for t, p, _ in msgs
                         if t == f"cutwatch/{n}/drive"]) for n in names]  # fmt: skip
    assert not np.array_equal(z[0], z[1])  # another seed: other noise


def test_a_simulated_feed_paces_at_the_trace_rate() -> None:
    argv = ["--machine", "vmc", "--seconds", "1.0", "--speed", "2"]
    with broker() as port:
        t0 = time.monotonic()
        msgs = _received(port, argv, ["cutwatch/vmc/drive"], 20)
        took = time.monotonic() - t0
    assert len(msgs) == 20 and took >= 0.5 * 0.95


def test_events_come_as_the_rate_says_and_broken_tools_are_replaced() -> None:
    feed = CentreFeed(0, 3, CentreFeedParams(event_rate=1.0, block_ms=1000.0))
    for i in range(160):  # 160 s: five parts
        feed.next_block(i)
    parts = [e.part for e in feed.events]
    assert parts == sorted(set(parts)) and len(parts) >= 4  # one event in each part
    broken = [e for e in feed.events if e.kind in ("breakage", "missing_tool")]
    assert broken
    # replaced at the end of its part: the tool in the magazine is a new, whole instance
    now = feed.state.part
    assert any(e.part < now for e in broken)
    hit_now = {e.tool for e in broken if e.part == now}
    tools = feed.state.tools
    assert all(not t.broken for n, t in tools.items() if n not in hit_now)
    assert all(tools[e.tool].instance >= 2 for e in broken if e.part < now)


@pytest.mark.parametrize(
    ("argv", "match"),
    [
        (["run.csv", "--simulate"], "one of the two"),
        ([], "neither"),
        (["--simulate", "--machines", "0"], "--machines"),
        (["--simulate", "--machine", "a,b"], "one name"),
        (["--simulate", "--rate", "700"], "rate_hz"),
    ],
)
def test_feed_simulate_refuses_what_it_cannot_do(
    argv: list[str], match: str, capsys: pytest.CaptureFixture[str]
) -> None:
    base = ["--broker", "mqtt://127.0.0.1:1", "--quiet"]
    if "--machine" not in argv:
        base += ["--machine", "m"]
    assert main(["feed", *argv, *base]) == 2
    assert match in capsys.readouterr().err
