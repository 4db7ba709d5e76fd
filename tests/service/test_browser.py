"""The dashboard in headless Chromium: it connects, the charts move, Pause stops them."""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from _browser import ARGS, MARKS, chromium_page, log_in, wait_for
from _live import OPERATOR, VIEWER, serve

pytestmark = MARKS


@pytest.fixture(scope="module")
def hp() -> Iterator[str]:
    with serve(scenario="default") as hostport:
        yield hostport


def test_dashboard_moves_and_pauses(hp: str, tmp_path: Path) -> None:
    with chromium_page(1280, 720) as (page, errors):
        page.goto(f"http://{hp}/#research")
        page.wait_for_selector("#conn[data-state=up]", timeout=15000)

        def sim_t() -> float:
            return float(page.get_attribute("#simt", "data-sim-t") or "nan")

        def frames() -> int:
            return int(page.get_attribute("body", "data-frames") or 0)

        wait_for(lambda: frames() > 10)
        # the two uPlot files the page needs loaded (served from the npm tree's dist);
        # the npm tree itself is not served
        assert page.evaluate("typeof uPlot") == "function"
        assert page.evaluate(
            "[...document.styleSheets].some(s => (s.href || '').endsWith('/uPlot.min.css')"
            " && s.cssRules.length > 0)"
        )
        for path in ("/package.json", "/node_modules/uplot/package.json"):
            assert page.evaluate(f"async () => (await fetch('{path}')).status") == 404
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
        # it moves: polled, as a loaded box may draw nothing new in a fixed 0.5 s
        wait_for(lambda: page.locator("#chart-force canvas").screenshot() != shot0)

        page.click("#pause")
        page.wait_for_selector("#simt:has-text('paused')", timeout=5000)
        t_paused = sim_t()
        # frames come in the loop's order, so none built before the pause follows the
        # one that said paused; a drawing it started may still be finishing: until two
        # shots in a row agree (was a fixed 0.3 s), then it must stay so
        shots = [page.locator("#chart-force canvas").screenshot()]
        wait_for(lambda: shots.append(page.locator("#chart-force canvas").screenshot())
                 or shots[-1] == shots[-2])  # fmt: skip
        still = shots[-1]
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


def test_knob_change_through_the_page(hp: str) -> None:
    import httpx

    with chromium_page(1280, 720) as (page, _errors):
        page.goto(f"http://{hp}/#research")
        page.wait_for_selector("#knob-weight_on", timeout=15000)
        page.check("#knob-weight_on")
        wait_for(lambda: httpx.get(f"http://{hp}/api/params").json()["weight_on"]["value"])
        # the tuner is a choice: a select, through PATCH
        page.select_option("#knob-tuner", "fast")
        wait_for(lambda: httpx.get(f"http://{hp}/api/params").json()["tuner"]["value"] == "fast")
        assert page.locator("#chart-ecc_radius canvas").count() == 1


def test_viser_scene_renders_and_moves(tmp_path: Path) -> None:
    # WebGL in software (SwiftShader): the 3D view is drawn, and the stage moves in it;
    # through the app's relay (/viser/), as every browser reaches it
    import io
    import socket

    import numpy as np
    from PIL import Image

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        vp = int(s.getsockname()[1])
    gl = [*ARGS, "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]
    with (
        serve(scenario="default", viser=True, viser_port=vp) as hostport,
        chromium_page(1280, 720, args=gl) as (page, _errors),
    ):
        page.goto(f"http://{hostport}/viser/")
        page.wait_for_selector("canvas", timeout=20000)

        def shot() -> np.ndarray:
            png = page.screenshot(clip={"x": 320, "y": 150, "width": 600, "height": 500})
            return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=float)

        # the stage's bed (90, 96, 110 with shading) covers a good part of the view
        def drawn(img: np.ndarray) -> float:
            return float(np.mean(np.abs(img - 255.0).sum(axis=2) > 60.0))

        wait_for(lambda: drawn(shot()) > 0.2, timeout=30.0)
        a = shot()

        def moved(b: np.ndarray) -> float:
            return float(np.mean(np.abs(a - b).sum(axis=2) > 30.0))

        # polled (was one shot 1 s later: a loaded box may not redraw the scene in 1 s)
        last: list[np.ndarray] = []
        wait_for(lambda: last.append(shot()) or moved(last[-1]) > 0.002, timeout=30.0)
        b = last[-1]
        page.screenshot(path=str(tmp_path / "viser.png"))
        out = Path("out")
        out.mkdir(exist_ok=True)
        page.screenshot(path=str(out / "viser.png"))
    assert drawn(a) > 0.2
    # the table, screw stripe and spindle move between the two shots
    assert moved(b) > 0.002


def test_refused_request_shows_the_servers_message() -> None:
    # the page reads the one error body ({"detail": [{field, allowed, got, msg}]}); a
    # viewer's session reads and streams, an operator's changes
    with (
        serve(scenario="default", token=OPERATOR, view_token=VIEWER) as hostport,
        chromium_page(1280, 720) as (page, errors),
    ):
        base = f"http://{hostport}"
        log_in(page, base, VIEWER)
        page.wait_for_selector("#conn[data-state=up]", timeout=15000)
        assert page.text_content("#session") == "signed in: viewer"
        assert page.evaluate("() => document.cookie") == ""  # HttpOnly: not readable
        assert page.evaluate("() => JSON.stringify(localStorage)") == "{}"
        page.click("#pause")  # a viewer: 403
        page.wait_for_selector("#error:has-text('operator')", timeout=5000)
        assert page.text_content("#error") == (
            "this request needs the operator role; this session is a viewer"
        )
        page.click("#logout")
        page.wait_for_url("**/login", timeout=5000)
        log_in(page, base, OPERATOR)
        page.wait_for_selector("#conn[data-state=up]", timeout=15000)
        page.click("#pause")
        page.wait_for_selector("#simt:has-text('paused')", timeout=5000)
        assert page.text_content("#error") == ""
        # an uncaught rejection of the refused click is the page's own (call() throws)
        assert all("operator" in e for e in errors)


def accuracy_numbers(page: Any) -> dict[str, list[float]]:
    """The accuracy table as the page shows it: row key -> its numbers."""
    rows: dict[str, list[str]] = page.evaluate(
        "() => Object.fromEntries([...document.querySelectorAll('#accuracy tbody tr')]"
        ".map((r) => [r.dataset.key, [...r.querySelectorAll('td[data-col]')]"
        ".map((c) => c.textContent)]))"
    )
    return {k: [float(v) if v != "–" else float("nan") for v in vs] for k, vs in rows.items()}


def watch_accuracy(page: Any, mode: str, estimates: tuple[str, ...]) -> None:
    """The panel is in ``mode``, shows a finite number for each estimate, and the numbers
    change as the stream goes on."""
    page.wait_for_selector(f"#accuracy-title[data-mode={mode}]", timeout=20000)
    wait_for(lambda: all(math.isfinite(v) for v in accuracy_numbers(page).get("f_fixed", [])))
    first = accuracy_numbers(page)
    assert set(estimates) <= set(first)
    for k in estimates:
        assert all(math.isfinite(v) and v >= 0.0 for v in first[k][:2]), (k, first[k])
    wait_for(lambda: accuracy_numbers(page) != first)  # rolling: the numbers move


def test_accuracy_panel_against_the_truth(hp: str) -> None:
    from server.pipeline.live_pipeline import FORCE_ESTIMATES

    with chromium_page(1280, 900) as (page, errors):
        page.goto(f"http://{hp}/#research")
        watch_accuracy(page, "truth", FORCE_ESTIMATES)
        title = page.text_content("#accuracy-title") or ""
        assert "against the truth" in title and "Q(s)" in title
        nums = accuracy_numbers(page)
        # with the truth: 1 s, 10 s against it, then against Q(s) truth; the Q filter's
        # own error is a row; the Q-limited observers are closer to Q(s)F than to F
        assert all(len(nums[k]) == 4 for k in FORCE_ESTIMATES)
        assert nums["q_floor"][0] > 0.0
        assert nums["f_adaptive"][2] < nums["f_adaptive"][0]
        wait_for(lambda: page.locator("#chart-accuracy canvas").count() == 1)
        out = Path("out")
        out.mkdir(exist_ok=True)
        page.locator("#accuracy-panel").screenshot(path=str(out / "accuracy-truth.png"))
        assert errors == []


def test_accuracy_panel_scores_a_replayed_log_against_its_measured_force(tmp_path: Path) -> None:
    import httpx

    from server.cli.main import main
    from server.pipeline.live_pipeline import FORCE_ESTIMATES

    data = tmp_path / "data"
    log = data / "recordings" / "run.csv"  # the service reads logs by name, from its areas
    log.parent.mkdir(parents=True)
    assert main(["simulate", "--out", str(log), "--seconds", "12"]) == 0
    with (
        serve(scenario="default", data_dir=data) as hostport,
        chromium_page(1280, 900) as (page, errors),
    ):
        page.goto(f"http://{hostport}/#research")
        page.wait_for_selector("#accuracy-title[data-mode=truth]", timeout=20000)
        r = httpx.post(f"http://{hostport}/api/replay", json={"name": "run"}, timeout=20)
        assert r.status_code == 200, r.text
        watch_accuracy(page, "measured_force", FORCE_ESTIMATES)
        title = page.text_content("#accuracy-title") or ""
        assert "against the measured force" in title and "truth," not in title
        nums = accuracy_numbers(page)
        assert "q_floor" not in nums  # no truth: no Q(s) truth either
        assert all(len(nums[k]) == 2 for k in FORCE_ESTIMATES)
        snap = httpx.get(f"http://{hostport}/api/snapshot").json()["pipeline"]["accuracy"]
        assert snap["mode"] == "measured_force" and snap["against"] == "measured_force"
        out = Path("out")
        out.mkdir(exist_ok=True)
        page.locator("#accuracy-panel").screenshot(path=str(out / "accuracy-measured-force.png"))
        assert errors == []


def colour_pixels(page: Any, selector: str, rgb: tuple[int, int, int], tol: int = 14) -> int:
    """Pixels of a chart's canvas within ``tol`` of ``rgb`` (opaque, over white)."""
    n: int = page.evaluate(
        "([sel, r, g, b, tol]) => { const c = document.querySelector(sel);"
        " const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;"
        " let n = 0; for (let i = 0; i < d.length; i += 4) {"
        "  const a = d[i + 3] / 255; if (!a) continue;"
        "  const px = [0, 1, 2].map((k) => d[i + k] * a + 255 * (1 - a));"
        "  if (Math.abs(px[0] - r) <= tol && Math.abs(px[1] - g) <= tol"
        "      && Math.abs(px[2] - b) <= tol) n++; } return n; }",
        [selector, *rgb, tol],
    )
    return n


# the band's fill, rgba(0, 158, 115, 0.18) over white, and the not-excited grey #9aa0a6
# (within 4 of it: its blue tint tells it from the neutral greys of anti-aliased black)
BAND_RGB = (209, 237, 230)
GREY_RGB = (154, 160, 166)


def test_interval_bands_and_the_not_excited_state(tmp_path: Path) -> None:
    # the real stream: the segment identifier's J_L is excited after the first reversals;
    # seed 000's weight put on (a known J_L change) restarts it: "not excited" until the
    # next reversal determines it again
    import httpx

    # the identified parameters with an interval: their charts (declared by the stage part)
    from server.pipeline.live_pipeline import LivePipeline

    intervals = [c.chart for c in LivePipeline("default").channels() if c.interval is not None]
    assert intervals == ["J_L", "B_L", "F_CL"]

    with serve(scenario="default") as hostport, chromium_page(1280, 900) as (page, errors):
        page.goto(f"http://{hostport}/#research")
        page.wait_for_selector("#conn[data-state=up]", timeout=20000)
        for q in intervals:  # every parameter's chart has its band series
            legend = page.text_content(f"#chart-{q} .u-legend") or ""
            assert "95 % upper" in legend and "not excited" in legend, legend

        def excited(q: str) -> str | None:
            return page.get_attribute(f"#flag-{q}", "data-excited")

        wait_for(lambda: all(excited(q) == "1" for q in intervals), timeout=30)
        assert all(page.is_hidden(f"#flag-{q}") for q in intervals)
        # the band grows as the stream goes on (J_L's is a few pixels high: +-4 %);
        # without the band, 7 pixels of this colour were measured (anti-aliasing)
        for q in intervals:
            wait_for(lambda q=q: colour_pixels(page, f"#chart-{q} canvas", BAND_RGB) > 150)
        out = Path("out")
        out.mkdir(exist_ok=True)
        page.locator("#chart-J_L").screenshot(path=str(out / "band-excited.png"))
        grey_before = colour_pixels(page, "#chart-J_L canvas", GREY_RGB, tol=4)

        r = httpx.patch(f"http://{hostport}/api/params", json={"weight_on": True})
        assert r.status_code == 200

        # flag shown, its text, its state and the legend read in one go (frames keep
        # arriving between separate reads on a loaded machine)
        def flag_state() -> list[Any]:
            return list(
                page.evaluate(
                    "() => { const e = document.querySelector('#flag-J_L');"
                    " const l = document.querySelector('#chart-J_L .u-legend');"
                    " return [!e.hidden && e.offsetParent !== null, e.textContent,"
                    " e.dataset.excited, l ? l.textContent : '']; }"
                )
            )

        wait_for(
            lambda: (
                flag_state()[:3] == [True, "not excited", "0"] and "not excited" in flag_state()[3]
            ),
            timeout=10,
        )

        # the estimate drawn greyed (dashed) while it is not determined: the whole
        # not-excited stretch (until the next clean reversal determines J_L again, about
        # 2.6 s of simulated time) stays grey in the chart's history; held still (paused)
        # so that a loaded machine's late drawing cannot miss it
        wait_for(lambda: excited("J_L") == "1", timeout=30)
        # and once more (the weight taken off): two stretches, about 20 grey pixels each
        # on this chart (one stretch measured +22 pixels after the merges shortened it)
        r = httpx.patch(f"http://{hostport}/api/params", json={"weight_on": False})
        assert r.status_code == 200
        wait_for(lambda: excited("J_L") == "0", timeout=10)
        wait_for(lambda: excited("J_L") == "1", timeout=30)
        pause = {"action": "pause"}
        assert httpx.post(f"http://{hostport}/api/control", json=pause).status_code == 200
        grey = [colour_pixels(page, "#chart-J_L canvas", GREY_RGB, tol=4)]
        deadline = time.monotonic() + 15
        while grey[-1] <= grey_before + 30 and time.monotonic() < deadline:
            time.sleep(0.2)
            grey.append(colour_pixels(page, "#chart-J_L canvas", GREY_RGB, tol=4))
        assert grey[-1] > grey_before + 30, (grey_before, grey[-5:])
        resume = {"action": "resume"}
        assert httpx.post(f"http://{hostport}/api/control", json=resume).status_code == 200
        page.locator("section:has(#chart-J_L)").screenshot(path=str(out / "band-not-excited.png"))
        # B_L and F_CL are not restarted by the weight: still excited
        assert excited("B_L") == "1" and excited("F_CL") == "1"
        wait_for(lambda: excited("J_L") == "1", timeout=30)  # determined again
        assert page.is_hidden("#flag-J_L")
        page.screenshot(path=str(out / "dashboard-bands.png"), full_page=True)
        assert errors == []
