"""The history's routes in process: the real app over a real SQLite history, the loop not run.

``GET /api/events`` is compared with the store's own answer for every filter, the
acknowledgement with what the store keeps, and the refusals with the one error shape.
"""

from __future__ import annotations

import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from test_routes import InProcess

from server.records.history import HistoryStore, default_url
from server.records.monitor_events import MonitorEvent
from server.service.app import create_app
from server.service.deps import live_loop
from server.service.hub import Hub
from server.service.loop import LiveLoop, loop_parts
from server.service.settings import Settings

OPERATOR = "operator-token-for-tests"
VIEWER = "viewer-token-for-tests"
OP = {"Authorization": f"Bearer {OPERATOR}"}
VIEW = {"Authorization": f"Bearer {VIEWER}"}


class Routed:
    def __init__(self, client: InProcess, store: HistoryStore, evs: list[MonitorEvent]) -> None:
        self.client, self.store, self.evs = client, store, evs


@pytest.fixture(scope="module")
def routed() -> Iterator[Routed]:
    with tempfile.TemporaryDirectory(prefix="cutwatch-data-") as tmp:
        s = Settings(
            scenario="default", viser=False, data_dir=tmp, token=OPERATOR, view_token=VIEWER
        )
        app = create_app(s)
        parts = loop_parts(s)  # the history as the service builds it
        assert parts.history is not None
        assert parts.history.url == default_url(Path(tmp))
        loop = LiveLoop(s, Hub(4), history=parts.history)
        app.dependency_overrides[live_loop] = lambda: loop
        evs = [
            MonitorEvent("breakage", "feed_hold", 1.0 + i, tool=1 + i % 3, value=2.0 + i)
            if i % 2
            else MonitorEvent("wear_limit", "alarm", 1.0 + i, tool=1 + i % 3)
            for i in range(12)
        ]
        for i, ev in enumerate(evs):
            parts.history.add_events([ev], wall=1000.0 + i)
        client = InProcess(app)
        yield Routed(client, parts.history, evs)
        client.close()
        parts.history.close()


def _ids(items: list[dict[str, Any]]) -> list[str]:
    return [d["id"] for d in items]


@pytest.mark.parametrize(
    "query",
    [
        {},
        {"kind": "breakage"},
        {"tool": 2},
        {"kind": "wear_limit", "tool": 1},
        {"since": 1003.0, "until": 1009.5},
        {"limit": 5, "offset": 3},
        {"limit": 5, "offset": 10},
    ],
)
def test_the_list_is_the_stores_filtered_page(routed: Routed, query: dict[str, Any]) -> None:
    r = routed.client.get("/api/events", params=query, headers=VIEW)
    assert r.status_code == 200, r.text
    total, items = routed.store.events(**query)
    body = r.json()
    assert body["total"] == total and _ids(body["items"]) == _ids(items)
    walls = [d["received_wall"] for d in body["items"]]
    assert walls == sorted(walls, reverse=True)  # newest first


def test_an_event_comes_back_with_every_field(routed: Routed) -> None:
    ev = routed.evs[5]
    r = routed.client.get("/api/events", params={"since": 1005.0, "until": 1006.0}, headers=VIEW)
    (item,) = r.json()["items"]
    want = {**ev.as_dict(), "machine": Settings().mqtt_machine}  # stamped: it carried none
    assert {k: item[k] for k in want} == want
    assert item["received_wall"] == 1005.0 and item["acked"] is False


def test_an_acknowledgement_is_kept_and_answered_again(routed: Routed) -> None:
    c, ev = routed.client, routed.evs[3]
    r = c.post(f"/api/events/{ev.id}/ack", headers=OP)
    assert r.status_code == 200, r.text
    first = r.json()
    assert first["id"] == ev.id and first["acked"] is True
    assert first["acked_by"] == "operator"  # the session's role when no name is given
    stored = routed.store.event(ev.id)
    assert stored is not None and stored["acked_wall"] == first["acked_wall"]
    again = c.post(f"/api/events/{ev.id}/ack", json={"by": "anna"}, headers=OP)
    assert again.status_code == 200 and again.json() == first  # idempotent
    named = c.post(f"/api/events/{routed.evs[4].id}/ack", json={"by": "anna"}, headers=OP)
    assert named.json()["acked_by"] == "anna"
    acked = c.get("/api/events", params={"acked": True}, headers=VIEW).json()
    assert set(_ids(acked["items"])) >= {ev.id, routed.evs[4].id}
    assert acked["total"] == routed.store.events(acked=True)[0]
    open_ = c.get("/api/events", params={"acked": False}, headers=VIEW).json()
    assert ev.id not in _ids(open_["items"])


def test_a_viewer_may_read_but_not_acknowledge(routed: Routed) -> None:
    ev = routed.evs[6]
    r = routed.client.post(f"/api/events/{ev.id}/ack", headers=VIEW)
    assert r.status_code == 403
    assert r.json()["detail"][0]["field"] == "role"
    assert routed.store.event(ev.id)["acked"] is False  # type: ignore[index]


def test_an_unknown_event_is_a_404_naming_its_id(routed: Routed) -> None:
    r = routed.client.post("/api/events/" + "f" * 32 + "/ack", headers=OP)
    assert r.status_code == 404
    (item,) = r.json()["detail"]
    assert item["field"] == "event_id" and item["got"] == "f" * 32
    assert "f" * 32 in item["msg"]


@pytest.mark.parametrize(
    ("url", "field", "got"),
    [
        ("/api/events?kind=chatter", "kind", "chatter"),
        ("/api/events?tool=-1", "tool", "-1"),
        ("/api/events?acked=perhaps", "acked", "perhaps"),
        ("/api/events?since=nan", "since", "nan"),
        ("/api/events?until=inf", "until", "inf"),
        ("/api/events?limit=0", "limit", "0"),
        ("/api/events?limit=100000", "limit", "100000"),
        ("/api/events?offset=-3", "offset", "-3"),
        ("/api/tool-life?tool=x", "tool", "x"),
        ("/api/tool-life?limit=2000", "limit", "2000"),
    ],
)
def test_a_bad_query_names_the_field_the_rule_and_the_value(
    routed: Routed, url: str, field: str, got: str
) -> None:
    r = routed.client.get(url, headers=VIEW)
    assert r.status_code == 422, r.text
    (item,) = r.json()["detail"]
    assert item["field"] == field and str(item["got"]) == got
    assert item["allowed"] and field in item["msg"]


def test_a_bad_acknowledgement_body_is_refused_whole(routed: Routed) -> None:
    ev = routed.evs[8]
    for body, field in (({"by": ""}, "by"), ({"who": "x"}, "who"), ({"by": 3}, "by")):
        r = routed.client.post(f"/api/events/{ev.id}/ack", json=body, headers=OP)
        assert r.status_code == 422, (body, r.text)
        assert r.json()["detail"][0]["field"] == field
    assert routed.store.event(ev.id)["acked"] is False  # type: ignore[index]


def test_tool_lives_are_listed_newest_first(routed: Routed) -> None:
    lives = [
        {"tool": 1, "index": 1, "start_t": 0.0, "end_t": 30.0, "cause": "wear_limit",
         "wear_at_change_mm": 0.28},
        {"tool": 1, "index": 2, "start_t": 30.0, "end_t": 61.0, "cause": "wear_limit",
         "wear_at_change_mm": 0.3},
        {"tool": 4, "index": 3, "start_t": 61.0, "end_t": 62.0, "cause": "breakage"},
    ]  # fmt: skip
    for i, c in enumerate(lives):
        routed.store.add_tool_changes([c], wall=2000.0 + i)
    body = routed.client.get("/api/tool-life", headers=VIEW).json()
    assert body["total"] == 3
    assert [d["end_t"] for d in body["items"]] == [62.0, 61.0, 30.0]
    assert body["items"][1]["start_wall"] == 2000.0  # mounted when the first was changed
    one = routed.client.get("/api/tool-life", params={"tool": 1, "limit": 1}, headers=VIEW)
    assert one.json()["total"] == 2 and one.json()["items"][0]["index"] == 2


def test_a_service_without_a_history_says_so() -> None:
    with tempfile.TemporaryDirectory(prefix="cutwatch-data-") as tmp:
        s = Settings(scenario="default", viser=False, data_dir=tmp, history_url="none")
        assert loop_parts(s).history is None
        app = create_app(s)
        loop = LiveLoop(s, Hub(4))
        app.dependency_overrides[live_loop] = lambda: loop
        client = InProcess(app)
        try:
            for method, url in (("GET", "/api/events"), ("POST", "/api/events/abc/ack"),
                                ("GET", "/api/tool-life")):  # fmt: skip
                r = client.request(method, url)
                assert r.status_code == 409, r.text
                assert r.json()["detail"][0]["field"] == "history"
        finally:
            client.close()
        assert not (Path(tmp) / "history").exists()
