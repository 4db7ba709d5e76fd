"""The viser 3D view: started and stopped by the lifespan, on its pinned port."""

from __future__ import annotations

import socket
import time

import httpx
import pytest
from _live import serve

from server.errors import CutwatchError
from server.service.viser_scene import StageScene, check_port_free


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_viser_port_answers_and_is_reported() -> None:
    vp = free_port()
    with serve(scenario="default", viser=True, viser_port=vp) as hp:
        h = httpx.get(f"http://{hp}/api/health").json()
        assert h["viser_port"] == vp and h["viser_running"] is True
        r = httpx.get(f"http://127.0.0.1:{vp}/", timeout=10)
        assert r.status_code == 200 and "<html" in r.text.lower()
    with pytest.raises(httpx.ConnectError):  # stopped with the service
        httpx.get(f"http://127.0.0.1:{vp}/", timeout=2)


def test_taken_port_fails_clearly_and_does_not_drift() -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        with pytest.raises(CutwatchError, match=rf"viser port {port} on 127.0.0.1 is not free"):
            check_port_free("127.0.0.1", port)
        with pytest.raises(CutwatchError, match=rf"viser port {port}"):
            StageScene("127.0.0.1", port)


def test_scene_updates_coalesce() -> None:
    # 1 Hz: the call right after an update must fall within its period; at 10 Hz a
    # loaded box could spend the 0.1 s in the first update itself (the skip then failed)
    scene = StageScene("127.0.0.1", free_port(), max_hz=1.0)
    try:
        latest = {
            "q_m": 1.0,
            "x_l": 0.05,
            "spindle_rpm": 3000.0,
            "f_true": 4.0,
            "f_adaptive": 3.5,
            "vb_true": 0.3,
            "vb_limit": 0.3,
        }
        assert not scene.update(latest, 0.3, 0.1)  # no viser client: nothing to do
        assert scene.update(latest, 0.3, 0.1, force=True)
        assert not scene.update(latest, 0.3, 0.15, force=True)  # within 1/max_hz: skipped
        time.sleep(1.01)
        assert scene.update(latest, 0.4, 0.2, force=True)
        assert scene.updates == 2
        assert tuple(scene.table.position) == pytest.approx((0.05, 0.0, 0.075))
        assert tuple(scene.tool.color) == (230, 0, 0)  # worn to the limit: red
    finally:
        scene.stop()
