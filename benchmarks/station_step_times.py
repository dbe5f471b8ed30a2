"""Time each step of the station on the simulated devices, through its pages in headless
Chromium, and print a table: from the click to the page showing the step's result.

    python benchmarks/station_step_times.py                 # this checkout's station
    python benchmarks/station_step_times.py --shots DIR     # and its pages saved at 1280 px

The station is started here on 127.0.0.1 at a free port, in a thread, with a fresh data folder
and record; the browser is Debian's ``chromium`` driven by Playwright (as the station's browser
tests). The motions run as the station runs them, in real time: the acquisition's sweeps take
about a minute, as on the robot. A motion's time runs from its confirmation's *Yes* to the run's
page showing that it ended, and counts the motion's own process starting (importing spacecal
and opening the devices) as well as the motion. Steps the station does not have are left out
(``--shots`` on an older station saves the pages it has: ``home``, ``workspace``, ``run``,
``trends``).
"""

from __future__ import annotations

import argparse
import functools
import shutil
import socket
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

#: Any step's bound, ms: a hang detector.
STEP_TIMEOUT_MS = 300_000
#: The verification's needle poses (the paper's 15 take minutes in real time).
VERIFY_POSES = 3
#: The run's page shows that it ended (however it ended).
RUN_ENDED_JS = "!['starting', 'running'].includes(document.getElementById('run-state').textContent)"


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def wait_js(page: Any, expression: str, timeout_s: float = STEP_TIMEOUT_MS / 1000) -> None:
    """Wait until the page's ``expression`` holds (through the debugging protocol: the station's
    content security policy forbids the ``eval`` of Playwright's own wait)."""
    deadline = time.monotonic() + timeout_s
    while not page.evaluate(expression):
        if time.monotonic() > deadline:
            raise TimeoutError(f"{expression} did not hold within {timeout_s:.0f} s")
        time.sleep(0.05)


def serve(data: Path) -> tuple[str, Any, Any, threading.Thread]:
    import uvicorn

    from spacecal.station.server import StationOptions, build, server_config

    port = free_port()
    station, application = build(StationOptions(port=port, data=str(data)))
    server = uvicorn.Server(server_config(application, "127.0.0.1", port))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    while not server.started:
        if not thread.is_alive():
            raise RuntimeError("the station did not start")
        time.sleep(0.05)
    return f"http://127.0.0.1:{port}", station, server, thread


class Steps:
    def __init__(self) -> None:
        self.times: list[tuple[str, float, str]] = []

    def timed(self, name: str, action: Any, note: str = "") -> Any:
        started = time.monotonic()
        out = action()
        self.times.append((name, time.monotonic() - started, note))
        return out

    def table(self) -> str:
        rows = ["| step | s | |", "|---|---:|---|"]
        rows += [f"| {name} | {seconds:.1f} | {note} |" for name, seconds, note in self.times]
        rows.append(f"| all of them | {sum(s for _, s, _ in self.times):.1f} | |")
        return "\n".join(rows)


def click_then(page: Any, button: str, shown: str) -> None:
    """Press ``button`` and wait for the page to show ``shown``."""
    page.click(button)
    page.wait_for_selector(shown)


def run_motion(page: Any, button: str, shots: Path | None = None, shot_name: str = "") -> str:
    """Open the motion's confirmation, confirm it, wait for the run's end: the run's message."""
    page.click(button)
    page.click("#confirm")
    page.wait_for_selector("#run-state")
    wait_js(page, RUN_ENDED_JS)
    state, message = page.inner_text("#run-state"), page.inner_text("#message")
    if state != "finished":
        raise RuntimeError(f"{button}: {state}: {message}")
    if shots is not None and shot_name:
        page.screenshot(path=str(shots / f"{shot_name}.png"), full_page=True)
    page.click("#back")
    page.wait_for_selector("#robot-name")
    return message


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shots", type=Path, help="save the home, workspace, run and trends pages here")
    parser.add_argument("--no-verify", action="store_true", help="leave out the verification on the robot")
    args = parser.parse_args(argv)
    from playwright.sync_api import sync_playwright

    binary = shutil.which("chromium") or shutil.which("chromium-browser")
    if binary is None:
        print("chromium is not installed", file=sys.stderr)
        return 1
    if args.shots is not None:
        args.shots.mkdir(parents=True, exist_ok=True)
    steps = Steps()
    with tempfile.TemporaryDirectory() as folder, sync_playwright() as playwright:
        url, station, server, thread = serve(Path(folder) / "station")
        browser = playwright.chromium.launch(executable_path=binary, args=["--no-sandbox"])
        try:
            page = browser.new_context(viewport={"width": 1280, "height": 900}).new_page()
            page.set_default_timeout(STEP_TIMEOUT_MS)

            def new_robot_and_tracker() -> None:
                page.goto(url + "/")
                page.fill("#add-robot input[name=name]", "UR10 (simulated)")
                page.click("#add-robot button")
                page.fill("#add-tracker input[name=name]", "Vicra (simulated)")
                page.click("#add-tracker button")
                page.click("#start button")
                page.wait_for_selector("#robot-name")

            steps.timed("new robot, tracker and calibration", new_robot_and_tracker)
            steps.timed("plan", lambda: click_then(page, "#plan", "#plan-summary"))
            steps.timed("dry run", lambda: click_then(page, "#dry-run", "#dry-run-result"))
            sweeps = "confirmed to ended; ~60 s of sweeps"
            steps.timed("acquire", lambda: run_motion(page, "#acquire"), sweeps)
            page.select_option("#method", "ml")
            steps.timed("calibrate", lambda: click_then(page, "#calibrate", "#verdict"))
            check = functools.partial(run_motion, page, "#check", args.shots, "run-1280")
            steps.timed("check", check, "confirmed to ended")
            if not args.no_verify and page.locator("#verify-dry-run").count():

                def verify_dry_run() -> None:
                    page.fill("#verify-poses", str(VERIFY_POSES))
                    page.click("#verify-dry-run")
                    page.wait_for_selector("#verify-dry-run-result")

                poses = f"{VERIFY_POSES} needle poses"
                steps.timed("verify: dry run", verify_dry_run, poses)
                steps.timed("verify on the robot", lambda: run_motion(page, "#verify"), poses)
            steps.timed("report", lambda: click_then(page, "#report", "#report-link"))

            def export() -> None:
                for box in ("slicer", "plus", "ros2_launch"):
                    page.check(f"#export-form input[name={box}]")
                page.click("#export")
                page.wait_for_selector("#exported a:text-is('tracker.launch.py')")

            steps.timed("export", export, "Slicer, PLUS, ROS 2 launch")
            if args.shots is not None:
                page.screenshot(path=str(args.shots / "workspace-1280.png"), full_page=True)
            steps.timed("trends", lambda: (page.goto(url + "/trends"), page.wait_for_selector("#checks")))
            if args.shots is not None:
                page.screenshot(path=str(args.shots / "trends-1280.png"), full_page=True)
                page.goto(url + "/")
                page.screenshot(path=str(args.shots / "home-1280.png"), full_page=True)
        finally:
            browser.close()
            station.runs.stop_all("the benchmark ended")
            server.should_exit = True
            thread.join(timeout=15)
            station.ledger.close()
    print(steps.table())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
