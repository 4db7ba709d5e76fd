"""A part written here, in the test, is drawn by the dashboard in a real Chromium: its chart
and legend come from the stream's hello, and no file of web/ is touched (issue 26).

The toy part declares a chart on the operator page and one channel; a second toy asks for
a signal the simulator does not deliver and is listed, on the page and in
``/api/health`` (``degraded``), with its reason. docs/adding-a-part.md walks through the
same part.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from _browser import MARKS, chromium_page, wait_for
from _live import serve

from server.pipeline.machine_view import MachineView
from server.pipeline.part import (
    Block,
    Channel,
    Chart,
    LivePart,
    Outputs,
    Verdict,
    needs_signals,
)
from server.pipeline.part_registry import registered

pytestmark = MARKS

WEB = Path(__file__).resolve().parents[2] / "web"
#: the toy's colour, magenta: no other chart of the page draws it
TOY_RGB = (216, 27, 96)


class ToyPart(LivePart):
    """A sine at 2 Hz of the machine's time, on a chart of its own."""

    name = "toy"
    charts = (Chart("toy", "Toy part: a 2 Hz sine", page="operator", order=5, window_s=4.0),)
    channels = charts[0].series(
        Channel("toy_sine", "1", "a 2 Hz sine of the machine's time", "toy",
                color="#d81b60", width=3.0, legend="toy sine"),
    )  # fmt: skip

    def step(self, block: Block) -> Outputs:
        return {"toy_sine": np.sin(2.0 * math.pi * 2.0 * block.t)}, []


class PickyPart(LivePart):
    """Needs the spindle's power, which the simulated stage does not deliver."""

    name = "picky"
    channels = (Channel("picky_power", "W", "spindle power, filtered", "picky"),)

    def requires(self, machine: MachineView) -> Verdict:
        return needs_signals(machine, "spindle_power", what="the spindle drive's power")

    def step(self, block: Block) -> Outputs:
        raise AssertionError("a part that cannot run is never stepped")


def web_digest() -> str:
    h = hashlib.sha256()
    for f in sorted(p for p in WEB.rglob("*") if p.is_file() and "node_modules" not in p.parts):
        h.update(f.relative_to(WEB).as_posix().encode())
        h.update(f.read_bytes())
    return h.hexdigest()


@pytest.fixture(scope="module")
def hp() -> Iterator[str]:
    with registered(ToyPart, PickyPart), serve(scenario="default") as hostport:
        yield hostport


def colour_pixels(page: Any, selector: str, rgb: tuple[int, int, int], tol: int = 30) -> int:
    n: int = page.evaluate(
        "([sel, r, g, b, tol]) => { const c = document.querySelector(sel);"
        " const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;"
        " let n = 0; for (let i = 0; i < d.length; i += 4) { if (d[i + 3] < 200) continue;"
        "  if (Math.abs(d[i] - r) <= tol && Math.abs(d[i + 1] - g) <= tol"
        "      && Math.abs(d[i + 2] - b) <= tol) n++; } return n; }",
        [selector, *rgb, tol],
    )
    return n


def test_the_toy_part_is_drawn_with_no_web_file_touched(hp: str) -> None:
    before = web_digest()
    with chromium_page(1280, 900) as (page, errors):
        page.goto(f"http://{hp}/")
        page.wait_for_selector("#chart-toy canvas", timeout=20000)
        # on the operator page, with its title and legend from the hello
        assert page.locator("#charts-operator #chart-toy").count() == 1
        assert page.text_content("#panel-toy h2") == "Toy part: a 2 Hz sine"
        assert "toy sine" in (page.text_content("#chart-toy .u-legend") or "")
        # its line drawn (about 1000 magenta pixels over 4 s of a 3 px sine)
        wait_for(lambda: colour_pixels(page, "#chart-toy canvas", TOY_RGB) > 300, timeout=30)
        # the parts: the toy runs, the picky one does not, with its reason
        row = page.locator("#parts tr[data-part=picky]")
        assert row.get_attribute("data-running") == "false"
        assert "spindle_power" in (row.text_content() or "")
        assert page.locator("#parts tr[data-part=toy]").get_attribute("data-running") == "true"
        out = Path("out")
        out.mkdir(exist_ok=True)
        page.locator("#panel-toy").screenshot(path=str(out / "toy-part.png"))
        assert errors == []
    assert web_digest() == before


def test_health_says_degraded_with_the_parts_and_their_reasons(hp: str) -> None:
    h = httpx.get(f"http://{hp}/api/health").json()
    assert h["status"] == "degraded"
    parts = {p["name"]: p for p in h["parts"]}
    assert parts["toy"] == {"name": "toy", "running": True, "reason": ""}
    assert not parts["picky"]["running"]
    assert parts["picky"]["reason"].startswith("needs the signal(s) spindle_power")
    assert all(parts[n]["running"] for n in ("stage", "dfo", "process", "eccentricity"))
