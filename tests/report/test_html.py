"""The HTML report renders in headless Chromium (the Debian ``chromium`` package) with every
plot drawn and no script error."""

import os
import re
import shutil
import subprocess
import tempfile

import numpy as np
import pytest

from spacecal.estimators import calibrate
from spacecal.experiments.verification import verify_in_simulation
from spacecal.report.html import Report, write_report
from spacecal.workflows.check import CheckResult

CHROMIUM_FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--virtual-time-budget=15000",
    "--dump-dom",
]


def chromium():
    binary = shutil.which("chromium") or shutil.which("chromium-browser")
    if binary is None:
        if os.environ.get("CI") == "true":
            pytest.fail("chromium is not installed (.ci/run installs the Debian package)")
        pytest.skip("chromium is not installed")
    return binary


def rendered_dom(path) -> str:
    with tempfile.TemporaryDirectory() as profile:
        result = subprocess.run(
            [chromium(), *CHROMIUM_FLAGS, f"--user-data-dir={profile}", path.as_uri()],
            capture_output=True,
            text=True,
            timeout=120,
        )
    assert result.returncode == 0, result.stderr[-500:]
    return result.stdout


def script_errors(dom: str) -> str:
    match = re.search(r'<div id="script-errors"[^>]*>(.*?)</div>', dom, re.S)
    assert match, "the error banner is missing from the page"
    return match.group(1).strip()


def plots_drawn(dom: str, count: int) -> list[bool]:
    drawn = []
    for k in range(1, count + 1):
        start = dom.find(f'id="plot-{k}"')
        end = dom.find(f'id="plot-{k + 1}"') if k < count else len(dom)
        drawn.append(start >= 0 and "main-svg" in dom[start:end])
    return drawn


@pytest.fixture(scope="module")
def full_report(tmp_path_factory, white_simulation):
    folder = tmp_path_factory.mktemp("report")
    calibration = calibrate(white_simulation.recording, "paper")
    verification = verify_in_simulation(calibration, white_simulation.world.scenario)
    history = [CheckResult(np.array([0.3, 0.4]), np.array([0.1, 0.1]), 1.0, 1.0, ["pose 1", "pose 2"])]
    report = Report(calibration, white_simulation.recording, verification, history)
    path, titles = write_report(report, folder / "report.html", png_dir=folder / "png")
    return path, titles, folder


def test_report_renders_every_plot_without_script_errors(full_report):
    path, titles, folder = full_report
    assert titles == ["Sweeps and fits", "Residuals", "Target errors", "Uncertainty", "Check history"]
    dom = rendered_dom(path)
    assert script_errors(dom) == ""
    assert all(plots_drawn(dom, len(titles)))
    assert (folder / "png" / "verification_errors.png").stat().st_size > 10_000


def test_report_is_self_contained(full_report):
    text = full_report[0].read_text()
    # nothing is loaded from elsewhere: no external scripts or stylesheets
    assert not re.search(r"<script[^>]+src=", text) and not re.search(r"<link[^>]+href=", text)
    assert len(text) > 3_000_000  # plotly.js is embedded


def test_the_check_catches_a_broken_page(full_report, tmp_path):
    broken = tmp_path / "broken.html"
    page = (
        full_report[0].read_text().replace("</body>", "<script>thisFunctionDoesNotExist();</script></body>")
    )
    broken.write_text(page.replace('id="plot-2"', 'id="plot-two"'))
    dom = rendered_dom(broken)
    assert "thisFunctionDoesNotExist" in script_errors(dom)
    assert not all(plots_drawn(dom, 5))
