"""The dashboard in headless Chromium: it connects, the charts move, Pause stops them."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from _live import serve

CHROMIUM = Path("/usr/bin/chromium")
ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
]

pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(not CHROMIUM.exists(), reason="/usr/bin/chromium is not installed"),
]


@pytest.fixture(scope="module")
def hp() -> Iterator[str]:
    with serve() as hostport:
        yield hostport


def wait_for(pred: Callable[[], object], timeout: float = 15.0) -> None:
    deadline = time.monotonic() + timeout
    while not pred():
        if time.monotonic() > deadline:
            raise AssertionError("condition not reached in time")
        time.sleep(0.1)


def test_dashboard_moves_and_pauses(hp: str, tmp_path: Path) -> None:
    sync_api = pytest.importorskip("playwright.sync_api")
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), args=ARGS)
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 720})
            errors: list[str] = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(f"http://{hp}/")
            page.wait_for_selector("#conn[data-state=up]", timeout=15000)

            def sim_t() -> float:
                return float(page.get_attribute("#simt", "data-sim-t") or "nan")

            def frames() -> int:
                return int(page.get_attribute("body", "data-frames") or 0)

            wait_for(lambda: frames() > 10)
            t0 = sim_t()
            wait_for(lambda: sim_t() > t0 + 0.3)  # the charts' time axis moves
            # the force chart has drawn data: its canvas is not blank
            drawn = page.evaluate(
                "() => { const c = document.querySelector('#chart-force canvas');"
                " const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;"
                " let n = 0; for (let i = 3; i < d.length; i += 4) if (d[i]) n++; return n; }"
            )
            assert drawn > 1000
            page.screenshot(path=str(tmp_path / "dashboard-running.png"))
            shot0 = page.locator("#chart-force canvas").screenshot()
            time.sleep(0.5)
            assert page.locator("#chart-force canvas").screenshot() != shot0  # it moves

            page.click("#pause")
            page.wait_for_selector("#simt:has-text('paused')", timeout=5000)
            t_paused = sim_t()
            time.sleep(0.3)  # a frame built before the pause may still arrive
            still = page.locator("#chart-force canvas").screenshot()
            time.sleep(1.0)
            assert sim_t() == t_paused
            assert page.locator("#chart-force canvas").screenshot() == still  # it stopped
            assert page.is_disabled("#pause") and not page.is_disabled("#resume")
            shot = Path("out") / "dashboard.png"
            shot.parent.mkdir(exist_ok=True)
            page.screenshot(path=str(shot), full_page=True)
            assert shot.stat().st_size > 10_000

            page.click("#resume")
            wait_for(lambda: sim_t() > t_paused + 0.2)
            assert errors == []
        finally:
            browser.close()


def test_knob_change_through_the_page(hp: str) -> None:
    import httpx

    sync_api = pytest.importorskip("playwright.sync_api")
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), args=ARGS)
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 720})
            page.goto(f"http://{hp}/")
            page.wait_for_selector("#knob-weight_on", timeout=15000)
            page.check("#knob-weight_on")
            wait_for(lambda: httpx.get(f"http://{hp}/api/params").json()["weight_on"]["value"])
            # the tuner is a choice: a select, through PATCH
            page.select_option("#knob-tuner", "fast")
            wait_for(
                lambda: httpx.get(f"http://{hp}/api/params").json()["tuner"]["value"] == "fast"
            )
            assert page.locator("#chart-ecc_radius canvas").count() == 1
        finally:
            browser.close()


def test_viser_scene_renders_and_moves(tmp_path: Path) -> None:
    # WebGL in software (SwiftShader): the 3D view is drawn, and the stage moves in it
    sync_api = pytest.importorskip("playwright.sync_api")
    import io
    import socket

    import numpy as np
    from PIL import Image

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        vp = int(s.getsockname()[1])
    gl = [*ARGS, "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]
    with serve(viser=True, viser_port=vp), sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), args=gl)
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 720})
            page.goto(f"http://127.0.0.1:{vp}/")
            page.wait_for_selector("canvas", timeout=20000)

            def shot() -> np.ndarray:
                png = page.screenshot(clip={"x": 320, "y": 150, "width": 600, "height": 500})
                return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=float)

            # the stage's bed (90, 96, 110 with shading) covers a good part of the view
            def drawn(img: np.ndarray) -> float:
                return float(np.mean(np.abs(img - 255.0).sum(axis=2) > 60.0))

            wait_for(lambda: drawn(shot()) > 0.2, timeout=30.0)
            a = shot()
            time.sleep(1.0)
            b = shot()
            page.screenshot(path=str(tmp_path / "viser.png"))
            out = Path("out")
            out.mkdir(exist_ok=True)
            page.screenshot(path=str(out / "viser.png"))
        finally:
            browser.close()
    assert drawn(a) > 0.2
    # the table, screw stripe and spindle move between the two shots
    assert float(np.mean(np.abs(a - b).sum(axis=2) > 30.0)) > 0.002


def test_refused_request_shows_the_servers_message() -> None:
    # the page reads the one error body ({"detail": [{field, allowed, got, msg}]})
    sync_api = pytest.importorskip("playwright.sync_api")
    with serve(token="s3cret") as hostport, sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), args=ARGS)
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 720})
            errors: list[str] = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(f"http://{hostport}/")
            page.wait_for_selector("#conn[data-state=up]", timeout=15000)
            page.click("#pause")  # no token: 401
            page.wait_for_selector("#error:has-text('Bearer')", timeout=5000)
            assert page.text_content("#error") == (
                "mutating endpoints need 'Authorization: Bearer <token>' (CUTWATCH_TOKEN)"
            )
            page.fill("#token", "s3cret")
            page.click("#pause")
            page.wait_for_selector("#simt:has-text('paused')", timeout=5000)
            assert page.text_content("#error") == ""
            # an uncaught rejection of the first click is the page's own (call() throws)
            assert all("Bearer" in e for e in errors)
        finally:
            browser.close()
