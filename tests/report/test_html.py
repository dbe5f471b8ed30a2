"""The HTML report renders in headless Chromium (the Debian ``chromium`` package) with every
plot drawn and no script error, its summary on the first screen, for every kind of result."""

import os
import re
import shutil
import subprocess
import tempfile

import numpy as np
import pytest

from spacecal.estimators import calibrate
from spacecal.experiments.verification import verify_in_simulation
from spacecal.geometry.transforms import make_transform
from spacecal.records import Provenance
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


def rendered_dom_in_window(path, width=1280, height=900) -> str:
    """The DOM after the page has loaded in a ``width`` x ``height`` window."""
    with tempfile.TemporaryDirectory() as profile:
        result = subprocess.run(
            [chromium(), *CHROMIUM_FLAGS, f"--window-size={width},{height}", f"--user-data-dir={profile}"]
            + [path.as_uri()],
            capture_output=True,
            text=True,
            timeout=120,
        )
    assert result.returncode == 0, result.stderr[-500:]
    return result.stdout


def screenshot(path, png, width=1280, height=900):
    """A PNG of the first screen of the page, as a person opening it sees it."""
    flags = [f for f in CHROMIUM_FLAGS if f != "--dump-dom"]
    with tempfile.TemporaryDirectory() as profile:
        result = subprocess.run(
            [chromium(), *flags, f"--window-size={width},{height}", f"--screenshot={png}"]
            + [f"--user-data-dir={profile}", path.as_uri()],
            capture_output=True,
            text=True,
            timeout=120,
        )
    assert result.returncode == 0, result.stderr[-500:]
    return png


def with_provenance(calibration, recording):
    """A calibration as ``spacecal calibrate`` writes it: simulated data, devices, scenario."""
    return calibration.replace(
        provenance=Provenance(
            simulated=True,
            scenario={"name": "paper-white", "seed": 1},
            devices={"robot": recording.metadata.get("robot"), "tracker": recording.metadata.get("tracker")},
        )
    )


@pytest.fixture(scope="module")
def calibrations(white_simulation):
    """One calibration per method family: the paper's, maximum likelihood, kinematic."""
    recording = white_simulation.recording
    return {m: with_provenance(calibrate(recording, m), recording) for m in ("paper", "ml", "kinematic")}


@pytest.fixture(scope="module")
def full_report(tmp_path_factory, white_simulation, calibrations):
    folder = tmp_path_factory.mktemp("report")
    calibration = calibrations["paper"]
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


def test_every_figure_is_also_a_png(full_report):
    folder = full_report[2]
    for name in ("sweeps", "residuals", "verification_errors", "uncertainty", "check_history"):
        assert (folder / "png" / f"{name}.png").stat().st_size > 10_000, name


MEASURE_FIRST_SCREEN = """<script>
window.addEventListener("load", function () {
  var verdict = document.getElementById("verdict").getBoundingClientRect();
  var plot = document.getElementById("plot-1").getBoundingClientRect();
  document.body.setAttribute("data-verdict-bottom", verdict.bottom);
  document.body.setAttribute("data-plot-top", plot.top);
  document.body.setAttribute("data-window-height", window.innerHeight);
});
</script></body>"""


def test_the_summary_is_the_first_screen(full_report, tmp_path):
    path = full_report[0]
    dom = rendered_dom_in_window(path)
    # in the document, the summary and its verdict come before the first plot ...
    assert 0 <= dom.find('id="summary"') < dom.find('id="verdict"') < dom.find('id="plot-1"')
    # ... and on the screen the verdict is within the first 1280 x 900 window, the plots below it
    measured = tmp_path / "measured.html"
    measured.write_text(path.read_text().replace("</body>", MEASURE_FIRST_SCREEN))
    dom = rendered_dom_in_window(measured)
    values = {
        key: float(re.search(rf'data-{key}="([0-9.]+)"', dom).group(1))
        for key in ("verdict-bottom", "plot-top", "window-height")
    }
    assert values["verdict-bottom"] <= values["window-height"] <= values["plot-top"]
    for text in ("tracker_from_base", "translation (mm)", "Polaris Vicra", "UR10", "SIMULATED", "spacecal "):
        assert text in dom[: dom.find('id="plot-1"')], text
    # kept for a person to look at: the first screen as a clinical engineer opens it
    shot = screenshot(path, tmp_path / "first_screen.png")
    assert shot.stat().st_size > 20_000


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


@pytest.mark.parametrize("method", ["paper", "ml", "kinematic"])
@pytest.mark.parametrize("with_recording", [True, False])
@pytest.mark.parametrize("with_evidence", [True, False])
def test_a_report_for_every_result_type(
    method, with_recording, with_evidence, calibrations, white_simulation, tmp_path
):
    calibration = calibrations[method]
    verification = history = None
    if with_evidence:
        verification = verify_in_simulation(calibration, white_simulation.world.scenario)
        history = [CheckResult(np.array([1.4]), np.array([0.2]), 1.0, 1.0)]  # one failed check
    report = Report(
        calibration, white_simulation.recording if with_recording else None, verification, history
    )
    path, titles = write_report(report, tmp_path / "r.html", png_dir=tmp_path / "png")
    page = path.read_text()
    assert f"method <b>{method}</b>" in page and "id='verdict'" in page
    assert ("Sweeps and fits" in titles) == with_recording
    assert "Residuals" in titles and "Uncertainty" in titles  # stored residuals when no recording
    assert ("Check history" in titles) == with_evidence
    if with_evidence:
        assert "failed" in page  # the failed check raises the red flag
    assert len(list((tmp_path / "png").glob("*.png"))) == len(titles)
    if method == "kinematic" and not with_recording and with_evidence:
        dom = rendered_dom(path)
        assert script_errors(dom) == "" and all(plots_drawn(dom, len(titles)))


def test_a_calibration_11_mm_off_shows_the_red_flag(calibrations, white_simulation, tmp_path):
    good = calibrations["ml"]
    assert good.verdict.grade == "good"
    path, _ = write_report(Report(good, white_simulation.recording), tmp_path / "good.html")
    assert "class='verdict ok'" in path.read_text()
    # the same file with tracker_from_base moved by 11 mm: its stored verdict still says good
    off = good.replace(tracker_from_base=make_transform(np.eye(3), [11.0, 0.0, 0.0]) @ good.tracker_from_base)
    path, _ = write_report(Report(off, white_simulation.recording), tmp_path / "off.html")
    page = path.read_text()
    assert "class='verdict alarm'" in page and "Do not use" in page
    assert re.search(r"marker residuals are 1[01]\.\d\d mm RMS", page)
    dom = rendered_dom_in_window(path)
    assert script_errors(dom) == ""
    screenshot(path, tmp_path / "off_first_screen.png")
