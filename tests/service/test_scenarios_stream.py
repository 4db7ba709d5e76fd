"""Issue 31: the service started with no scenario runs the machining centre, and every
scenario (the seeds' ones as before, the centre) still streams through the real app:
switched to by name (``POST /api/control``), each sends its hello, then frames whose
samples move on from the start with finite values in its own channels."""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from typing import Any

import httpx
import pytest
from _live import serve
from websockets.sync.client import ClientConnection, connect

from server.pipeline.scenarios import DEFAULT_SCENARIO, SCENARIOS


@pytest.fixture(scope="module")
def hp() -> Iterator[str]:
    with serve() as hostport:  # no scenario: the default
        yield hostport


def recv(ws: ClientConnection) -> dict[str, Any]:
    msg: dict[str, Any] = json.loads(ws.recv(timeout=10))
    return msg


def test_the_service_starts_on_the_machining_centre(hp: str) -> None:
    assert DEFAULT_SCENARIO == "machining-centre"
    with httpx.Client(base_url=f"http://{hp}", timeout=10) as api:
        assert api.get("/api/scenarios").json()["current"] == "machining-centre"
        m = api.get("/api/machine").json()
        assert [a["name"] for a in m["axes"]] == ["X", "Y", "Z"] and m["spindle"]
    with connect(f"ws://{hp}/ws") as ws:
        hello = recv(ws)
        assert hello["scenario"] == "machining-centre"
        assert hello["sample_time"] == pytest.approx(0.002)  # the CNC's 500 Hz trace


@pytest.mark.parametrize(
    "name", [*(n for n in SCENARIOS if n != DEFAULT_SCENARIO), DEFAULT_SCENARIO]
)
def test_every_scenario_streams_by_name(hp: str, name: str) -> None:
    with connect(f"ws://{hp}/ws") as ws, httpx.Client(base_url=f"http://{hp}") as api:
        recv(ws)
        r = api.post("/api/control", json={"action": "scenario", "scenario": name}, timeout=60)
        assert r.status_code == 200, r.text
        # frames of the old pipeline may still be queued: read until its hello
        msgs = [recv(ws) for _ in range(1)]
        while not (msgs[-1]["type"] == "hello" and msgs[-1]["scenario"] == name):
            assert len(msgs) < 400, [m["type"] for m in msgs[-5:]]
            msgs.append(recv(ws))
        hello = msgs[-1]
        names = {c["name"] for c in hello["channels"]}
        frames = []
        while sum(len(f["t"]) for f in frames) < 40:
            f = recv(ws)
            assert f["type"] in ("data", "event"), f["type"]
            # a frame published when no block came since the last one (the loop behind,
            # under load) carries health and status but no samples and no channels
            if f["type"] == "data" and f["t"]:
                frames.append(f)
    ts = [t for f in frames for t in f["t"]]
    # from the start (a block's first sample is stamped one sample before t = 0)
    assert ts == sorted(ts) and ts[0] >= -hello["sample_time"] - 1e-9 and ts[-1] > ts[0]
    # every frame carries the hello's channels, and at least one of them has numbers
    for f in frames:
        assert set(f["ch"]) == names, (name, f["seq"], len(f["t"]), sorted(set(f["ch"]) ^ names))
    finite = {k for f in frames for k, v in f["ch"].items() if any(
        x is not None and math.isfinite(x) for x in v)}  # fmt: skip
    assert len(finite) >= 3, (name, sorted(finite))
