"""viser behind the app: its own port on loopback only, its page and WebSocket relayed at
``/viser/`` behind the app's session, its share feature off. A real Chromium loads the
dashboard and the embedded 3D view through the relay; without a session it is refused."""

from __future__ import annotations

import json
import logging
import socket
import time
from typing import Any

import httpx
import pytest
import viser
from _browser import MARKS, chromium_page, log_in, wait_for
from _live import OPERATOR, VIEWER, serve
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from server.service.viser_scene import StageScene

SUBPROTOCOL = f"viser-v{viser.__version__}"
#: viser's share request as its client sends it: a msgpack map {"type": "ShareUrlRequest"}
SHARE_REQUEST = b"\x81\xa4type\xafShareUrlRequest"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def own_address() -> str | None:
    """This host's address on its default route (not loopback), if it has one."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.connect(("192.0.2.1", 9))  # TEST-NET-1: no packet is sent for a UDP connect
        except OSError:
            return None
        ip = str(s.getsockname()[0])
    return None if ip.startswith("127.") else ip


def test_viser_listens_on_loopback_only() -> None:
    vp = free_port()
    with serve(scenario="default", viser=True, viser_port=vp):
        assert httpx.get(f"http://127.0.0.1:{vp}/", timeout=10).status_code == 200
        ip = own_address()
        if ip is None:
            pytest.skip("no address besides loopback to try")
        with pytest.raises(OSError), socket.create_connection((ip, vp), timeout=2):
            pass


def test_without_a_session_the_proxy_refuses() -> None:
    vp = free_port()
    with serve(
        scenario="default", token=OPERATOR, view_token=VIEWER, viser=True, viser_port=vp
    ) as hp:
        base = f"http://{hp}"
        r = httpx.get(f"{base}/viser/", timeout=10)
        assert r.status_code == 401 and r.json()["detail"][0]["field"] == "authorization"
        page = httpx.get(f"{base}/viser/", headers={"Accept": "text/html"}, timeout=10)
        assert page.status_code == 303 and page.headers["location"] == "/login"
        with pytest.raises(InvalidStatus) as e:
            connect(f"ws://{hp}/viser/", subprotocols=[SUBPROTOCOL], open_timeout=10)  # type: ignore[list-item]
        assert e.value.response.status_code == 401
        # a viewer's token: the page, framed by this origin only, and the WebSocket
        auth = {"Authorization": f"Bearer {VIEWER}"}
        ok = httpx.get(f"{base}/viser/", headers=auth, timeout=10)
        assert ok.status_code == 200 and "<html" in ok.text.lower()
        assert ok.headers["x-frame-options"] == "SAMEORIGIN"
        assert "frame-ancestors 'self'" in ok.headers["content-security-policy"]
        with connect(
            f"ws://{hp}/viser/", subprotocols=[SUBPROTOCOL], additional_headers=auth,  # type: ignore[list-item]
            open_timeout=10,
        ) as ws:  # fmt: skip
            assert ws.subprotocol == SUBPROTOCOL
            assert isinstance(ws.recv(timeout=10), bytes)  # viser's scene messages
        # another site's page cannot open it, even with the credentials
        with pytest.raises(InvalidStatus):
            connect(
                f"ws://{hp}/viser/", subprotocols=[SUBPROTOCOL],  # type: ignore[list-item]
                additional_headers={**auth, "Origin": "http://attacker.example"},
                open_timeout=10,
            )  # fmt: skip


def test_share_requests_never_reach_the_network(caplog: pytest.LogCaptureFixture) -> None:
    # viser itself: the handlers are gone, the method refuses, the button is hidden
    vp = free_port()
    scene = StageScene("127.0.0.1", vp)
    try:
        with connect(f"ws://127.0.0.1:{vp}/", subprotocols=[SUBPROTOCOL]) as ws:  # type: ignore[list-item]
            ws.send(SHARE_REQUEST)
            time.sleep(1.0)
        assert scene.server._share_tunnel is None
        assert scene.server.request_share_url() is None
    finally:
        scene.stop()
    # through the app: the relay drops it before viser sees it
    vp = free_port()
    with (
        serve(scenario="default", viser=True, viser_port=vp) as hp,
        caplog.at_level(logging.WARNING, "cutwatch.viser"),
    ):
        with connect(f"ws://{hp}/viser/", subprotocols=[SUBPROTOCOL]) as ws:  # type: ignore[list-item]
            ws.recv(timeout=10)
            ws.send(SHARE_REQUEST)
            wait_for(lambda: "share request" in caplog.text, timeout=10)


@MARKS[0]
@MARKS[1]
def test_a_browser_sees_the_3d_view_through_the_dashboard() -> None:
    """Logged in as a viewer, the dashboard's iframe loads /viser/ from the app's origin
    and viser's WebSocket opens through the relay and carries the scene."""
    vp = free_port()
    sockets: list[dict[str, Any]] = []
    with (
        serve(
            scenario="default", token=OPERATOR, view_token=VIEWER, viser=True, viser_port=vp
        ) as hp,
        chromium_page(1280, 900) as (page, errors),
    ):
        base = f"http://{hp}"

        def opened(ws: Any) -> None:
            rec: dict[str, Any] = {"url": ws.url, "frames": 0}
            ws.on("framereceived", lambda _f: rec.__setitem__("frames", rec["frames"] + 1))
            sockets.append(rec)

        page.on("websocket", opened)
        log_in(page, base, VIEWER)
        page.click("#tab-research")  # the 3D view is on the research page (issue 31)
        page.wait_for_selector("#viser-panel:not([hidden])", timeout=15000)
        assert page.get_attribute("#viser", "src") == f"{base}/viser/"
        frame = page.frame_locator("#viser")
        frame.locator("canvas").first.wait_for(timeout=30000)
        try:
            wait_for(
                lambda: any(s["url"] == f"ws://{hp}/viser" and s["frames"] > 0 for s in sockets)
            )
        except AssertionError:
            raise AssertionError(f"no viser WebSocket through the relay: {sockets}") from None
        assert not any(f":{vp}" in s["url"] for s in sockets)  # never viser's own port
        assert errors == []
        # the dashboard's own stream too
        assert any(s["url"] == f"ws://{hp}/ws" for s in sockets)
        health = json.loads(page.evaluate("() => fetch('/api/health').then(r => r.text())"))
        assert health["viser_running"] is True
