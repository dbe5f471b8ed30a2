"""Every page of the station at a desktop's and a tablet's width (1280 and 768 px) in headless
Chromium: no horizontal scroll, and no serious or critical violation in an axe-core scan; STOP
reached by the keyboard alone and pressed with Space and with Enter.

axe-core comes from npm, never from the station's wheel: ``SPACECAL_AXE_JS`` names its
``axe.min.js``, or it is looked for where ``npm install --prefix build/axe axe-core@4`` puts it.
In CI (CI=true) a missing axe-core fails the scan; elsewhere it skips.
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path
from typing import Any

import pytest

from tests.station.conftest import BROWSER_TIMEOUT_MS, IN_CI, wait_js
from tests.station.test_browser import RUN_ENDED_JS, new_robot_and_tracker, wait_for_run_end
from tests.station.test_stepper import acquire_at_once

#: The widths every page must fit: a desktop's and a tablet's (portrait), px; and their heights.
WIDTHS = {1280: 900, 768: 1024}
#: Where axe-core's script is: the variable, else where .ci/run's npm install puts it.
AXE_ENV = "SPACECAL_AXE_JS"
AXE_DEFAULT = Path(__file__).resolve().parents[2] / "build/axe/node_modules/axe-core/axe.min.js"
#: The impacts a page may not have.
BLOCKING = ("serious", "critical")
#: How many Tab presses STOP may take from the top of the run's page (the header's two links
#: come first).
TABS_TO_STOP = 6


def axe_script() -> Path:
    """axe-core's ``axe.min.js`` (skipped when absent, failing in CI)."""
    path = Path(os.environ.get(AXE_ENV) or AXE_DEFAULT)
    if not path.is_file():
        message = f"axe-core is not at {path} (npm install --prefix build/axe axe-core@4, or set {AXE_ENV})"
        if IN_CI:
            pytest.fail(message + ": .ci/run installs it")
        pytest.skip(message)
    return path


@pytest.fixture
def scanned_page(browser_context) -> Any:
    """A page whose context lets a test's script tag in past the station's content security
    policy (axe-core is injected as a script element; the station's own pages never are)."""
    context = browser_context.browser.new_context(bypass_csp=True, viewport={"width": 1280, "height": 900})
    context.set_default_timeout(BROWSER_TIMEOUT_MS)
    try:
        yield context.new_page()
    finally:
        context.close()


def overflow(page) -> tuple[int, int]:
    """``(scrollWidth, innerWidth)`` of the page, px."""
    return tuple(page.evaluate("[document.documentElement.scrollWidth, window.innerWidth]"))


def violations(page, axe: Path) -> list[dict[str, Any]]:
    """axe-core's serious and critical violations of the page as it stands."""
    if not page.evaluate("typeof window.axe !== 'undefined'"):
        page.add_script_tag(path=str(axe))
    found = page.evaluate("axe.run(document).then(r => r.violations)")
    return [
        {"id": v["id"], "impact": v["impact"], "nodes": [n["target"] for n in v["nodes"]][:5]}
        for v in found
        if v["impact"] in BLOCKING
    ]


class Pages:
    """Checks each page at both widths, keeping the widths measured and what failed."""

    def __init__(self, page, axe: Path) -> None:
        self.page, self.axe = page, axe
        self.widths: dict[str, dict[int, tuple[int, int]]] = {}
        self.failures: list[str] = []

    def check(self, name: str) -> None:
        for width, height in WIDTHS.items():
            self.page.set_viewport_size({"width": width, "height": height})
            self.page.wait_for_timeout(300)  # the page's layout (and plotly's resize) settle
            scroll, inner = overflow(self.page)
            self.widths.setdefault(name, {})[width] = (scroll, inner)
            if scroll > inner:
                self.failures.append(f"{name} at {width} px: {scroll} px wide")
            found = violations(self.page, self.axe)
            if found:
                self.failures.append(f"{name} at {width} px: {json.dumps(found)}")
            shot_viewport(self.page, f"{name}-{width}")
        self.page.set_viewport_size({"width": 1280, "height": 900})


def shot_viewport(page, name: str) -> None:
    """A screenshot of what the window shows (``SPACECAL_STATION_SHOTS``), kept modest in size."""
    folder = os.environ.get("SPACECAL_STATION_SHOTS")
    if folder:
        Path(folder).mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(Path(folder) / f"{name}.png"))


def stop_by_keyboard(page, key: str) -> None:
    """Tab from the top of the run's page to STOP and press it with ``key``."""
    page.evaluate("document.activeElement && document.activeElement.blur()")
    for _ in range(TABS_TO_STOP):
        page.keyboard.press("Tab")
        if page.evaluate("document.activeElement.id") == "stop":
            break
    assert page.evaluate("document.activeElement.id") == "stop", "STOP is not reached with Tab"
    page.keyboard.press(key)


def start_check(page) -> None:
    page.click("#check")
    page.click("#confirm")
    page.wait_for_url(re.compile(r"/runs/\d+$"))
    wait_js(page, "['running', 'starting'].includes(document.getElementById('run-state').textContent)")


def test_every_page_fits_a_tablet_and_passes_the_scan(served, scanned_page, disk):
    axe = axe_script()
    page = scanned_page
    pages = Pages(page, axe)
    new_robot_and_tracker(page, served.url, "UR10 bay 12")
    page.goto(served.url + "/")
    pages.check("home")
    page.goto(served.url + "/workspaces/1")
    pages.check("workspace-new")
    page.click("#plan")
    page.click("#dry-run")
    assert "motion gate: passed" in page.inner_text("#dry-run-result")
    pages.check("workspace-dry-run")
    page.click("#acquire")
    pages.check("confirm")
    acquire_at_once(served.station.workspace(1))
    page.goto(served.url + "/workspaces/1")
    page.click("#calibrate")
    page.click("#report")
    pages.check("workspace-calibrated")

    # the run's page while the check moves; STOP by the keyboard alone, once with Space and
    # once with Enter
    for n, key in enumerate(("Space", "Enter"), start=1):
        start_check(page)
        if n == 1:
            pages.check("run")
        stop_by_keyboard(page, key)
        wait_js(page, RUN_ENDED_JS)
        assert page.inner_text("#run-state") == "stopped", page.inner_text("#message")
        assert "STOP pressed at the station" in page.inner_text("#message")
        run = served.station.runs.get(n)
        assert run.stop_reason == "STOP pressed at the station"
        if n == 1:
            pages.check("run-stopped")
        page.click("#back")
    assert served.station.ledger.checks() == []  # a stopped check logs nothing
    # a check to its end: the calibration's page with a check done, the trends with a check
    start_check(page)
    wait_for_run_end(page, disk, RUN_ENDED_JS)
    assert page.inner_text("#run-state") == "finished", page.inner_text("#message")
    page.click("#back")
    assert page.get_attribute("#stepper-check", "data-state") == "done"
    pages.check("workspace-checked")

    page.goto(served.url + "/trends")
    pages.check("trends")
    assert page.goto(served.url + "/workspaces/999").status == 404
    pages.check("error")
    print("\nscrollWidth/innerWidth, px: " + json.dumps(pages.widths), flush=True)
    assert not pages.failures, "\n".join(pages.failures)


def test_the_scan_finds_what_it_is_for(served, scanned_page):
    """The scan is not blind: a page given an unlabelled field and a low-contrast line has
    serious violations (so an empty list means the station's pages have none)."""
    axe = axe_script()
    page = scanned_page
    page.goto(served.url + "/")
    page.evaluate(
        "document.querySelector('main').insertAdjacentHTML('beforeend',"
        ' \'<input id="bare"><p style="color:#ccc;background:#fff">faint</p>\')'
    )
    found = {v["id"] for v in violations(page, axe)}
    assert {"label", "color-contrast"} <= found, found
