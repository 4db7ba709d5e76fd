"""The residual loop closed from the dashboard, in headless Chromium: record a simulated
run with an unmodelled effect (friction that differs by direction), analyse the
recording in the background, open its report, install the selected effects into the
live observer with one click, and read the live error before and after."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from _browser import MARKS, chromium_page, wait_for
from _live import serve

OUT = Path(__file__).resolve().parents[2] / "out"

pytestmark = MARKS


@pytest.fixture(scope="module")
def hp(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    # seed 001's stage: the plant stays the same all run (the spindle drop at 11 s
    # changes the cutting force only)
    with serve(data_dir=tmp_path_factory.mktemp("data"), scenario="seed001-spindle") as h:
        yield h


def test_record_analyse_install_from_the_dashboard(hp: str) -> None:
    with httpx.Client(base_url=f"http://{hp}", timeout=30) as api:  # the plant's effect on
        assert api.patch("/api/params", json={"effect_coulomb_asymmetry": True}).is_success
        assert api.post("/api/control", json={"action": "reset"}).is_success
    with chromium_page(1280, 1400) as (page, errors):
        page.goto(f"http://{hp}/#research")
        page.wait_for_selector("#conn[data-state=up]", timeout=30000)

        def text(sel: str) -> str:
            return page.locator(sel).inner_text()

        def value(sel: str) -> float:
            return float(page.get_attribute(sel, "data-value") or "nan")

        # record a few seconds of the live run
        page.click("#record")
        page.wait_for_selector("#record[data-state=recording]", timeout=10000)
        wait_for(lambda: "recording rec-" in text("#record-status"), 30)
        wait_for(lambda: float(text("#record-status").split(": ")[1].split(" s")[0]) > 6.0, 30)
        page.click("#record")
        page.wait_for_selector("#record[data-state=idle]", timeout=10000)
        # the periodic refresh may show idle before the stop's own answer names the log
        wait_for(lambda: "recorded rec-" in text("#record-status"), 10)
        assert page.locator("#loop-log").input_value().startswith('{"log":"rec-')

        # analyse it in the background: the progress moves, the report opens
        page.click("#analyse")
        seen: list[float] = []

        def finished() -> bool:
            seen.append(float(page.get_attribute("#analysis-progress", "value") or 0))
            return page.get_attribute("#analysis-progress", "data-state") in ("done", "failed")

        wait_for(finished, 300)
        seen.append(float(page.get_attribute("#analysis-progress", "value") or 0))
        status = text("#analysis-status")
        assert status.startswith("done: rec-"), status
        assert "offset" in status or "coulomb_asymmetry" in status, status
        assert seen == sorted(seen) and seen[-1] == 1.0
        assert any(0 < v < 1 for v in seen), seen  # progress shown under way
        with page.expect_popup() as pop:
            page.click("#report-link")
        report = pop.value
        report.wait_for_load_state()
        assert "/residual/rec-" in report.url and report.locator("table").count() > 0
        report.close()

        # install with one click; the live error before and after
        wait_for(lambda: value("#err-now-effects-level") > 0, 10)
        page.click("#install")
        page.wait_for_selector("#installed:has-text('installed: ')", timeout=10000)
        assert "offset" in text("#installed") or "coulomb" in text("#installed")
        wait_for(lambda: value("#err-after-effects-level") > 0, 60)
        before = {k: value(f"#err-before-{k}") for k in ("fixed", "effects", "fixed-level",
                                                           "effects-level")}  # fmt: skip
        after = {k: value(f"#err-after-{k}") for k in before}
        page.locator("#loop-panel").scroll_into_view_if_needed()
        OUT.mkdir(exist_ok=True)
        page.screenshot(path=str(OUT / "dashboard-residual-loop.png"), full_page=True)
        print(f"live error before {before}, after {after}")
        # before the install the corrected channel is the fixed observer's
        assert before["effects"] == pytest.approx(before["fixed"], rel=1e-6)
        # after: the level of the error (what the effect shifts) falls by far, the
        # fixed observer's stays
        assert after["effects-level"] < 0.3 * before["effects-level"]
        assert after["fixed-level"] > 0.5 * before["fixed-level"]
        assert after["effects"] < after["fixed"]
        assert not errors, errors
