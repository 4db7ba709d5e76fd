"""``GET /api/machine`` (issue 31): the machine the source delivers and its parts, from a
real server, on the stage's default scenario and on the machining centre (switched to by
name over ``POST /api/control``; and started on it, its checkpoint saved every second)."""

from __future__ import annotations

import math

import httpx
from _live import serve
from _wait import poll


def test_the_machine_of_the_stage_and_of_the_centre() -> None:
    with serve(scenario="default") as hp, httpx.Client(base_url=f"http://{hp}", timeout=60) as api:
        m = api.get("/api/machine").json()
        assert m["scenario"] == "default" and m["source"] == "simulator"
        assert [(a["name"], a["kind"]) for a in m["axes"]] == [("X", "two_inertia")]
        assert m["spindle"] is None and m["description"] is None
        parts = {p["name"]: p for p in m["parts"]}
        assert parts["stage"]["running"] and parts["process"]["running"]
        assert "spindle" not in parts and "axes" not in parts

        r = api.post("/api/control", json={"action": "scenario", "scenario": "machining-centre"})
        assert r.status_code == 200, r.text
        m = api.get("/api/machine").json()
        assert m["scenario"] == "machining-centre" and m["source"] == "centre"
        assert [a["name"] for a in m["axes"]] == ["X", "Y", "Z"]
        assert m["sample_time"] == 0.002 and "power" in m["spindle"]["signals"]
        assert set(m["description"]["axes"]) == {"X", "Y", "Z"}
        parts = {p["name"]: p for p in m["parts"]}
        assert parts["spindle"]["running"] and parts["axes"]["running"]
        assert not parts["stage"]["running"] and "nominal" in parts["stage"]["reason"]

        streams(api)


def test_started_on_the_centre_it_streams_and_keeps_its_checkpoint() -> None:
    with (
        serve(scenario="machining-centre", checkpoint_s=1.0) as hp,
        httpx.Client(base_url=f"http://{hp}", timeout=60) as api,
    ):
        streams(api)

        def saved() -> float:
            return float(api.get("/api/snapshot").json()["pipeline"]["checkpoint"]["saved_t"])

        first = poll(lambda: saved() > 0 and saved(), 15, 0.2)
        poll(lambda: saved() > first, 15, 0.2)


def streams(api: httpx.Client) -> None:
    """The spindle's power and the axes' force in the snapshot, the strip with the CNC's
    program and tool, the loop running."""

    def latest() -> dict:
        return dict(api.get("/api/snapshot").json()["pipeline"]["latest"])

    poll(lambda: math.isfinite(latest().get("spindle_power") or math.nan), 30, 0.2)
    snap = api.get("/api/snapshot").json()
    assert snap["status"]["program"] == "O2001" and snap["status"]["tool"] > 0
    assert "X.F" in snap["pipeline"]["latest"]
    assert api.get("/api/health").json()["loop_error"] is None
