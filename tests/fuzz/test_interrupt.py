"""Ctrl-C and SIGTERM at seeded random points of ``spacecal acquire`` on simulated devices.

After each interruption every file written must be readable, ``--resume`` must complete the
recording (time increasing across the resume point, the same columns) and the recording must
calibrate (``--method ml``). The interrupted and the resumed acquisitions are each a process of
their own, as on a real machine; the calibration runs in this process (what a process leaves
behind is the files, and they are what it reads).
"""

from __future__ import annotations

import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from spacecal import app
from spacecal.core.errors import SpacecalError
from spacecal.io.recording_csv import read_recording

#: Interruption points, one in each of as many equal slices of 1-7 s after the start (each
#: point costs a whole simulated acquisition); the in-process test below hits every part of
#: the plan by sample instead, at as many points.
POINTS = 20
#: Samples of the simulated plan the in-process test interrupts (paper-white's sweeps).
PLAN_SAMPLES = 560
SEED = 20240611


def _spacecal(*argv: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "spacecal", *argv], cwd=cwd, capture_output=True, text=True, timeout=180
    )


def _interrupt_then_resume(folder: Path, signum: int, delay_s: float) -> str | None:
    """None when the run ends in a recording that calibrates; else what went wrong."""
    folder.mkdir(parents=True)
    argv = ["acquire", "--scenario", "paper-white", "-o", "rec.csv"]
    process = subprocess.Popen(
        [sys.executable, "-m", "spacecal", *argv],
        cwd=folder,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    time.sleep(delay_s)
    process.send_signal(signum)
    _, err = process.communicate(timeout=120)
    if "Traceback" in err and process.returncode not in (-signum, 128 + signum):
        return f"traceback after {signal.Signals(signum).name} at {delay_s:.2f} s:\n{err[-1500:]}"
    header = None
    if (folder / "rec.csv").is_file():
        lines = (folder / "rec.csv").read_text().splitlines()
        header = lines[0] if lines else None
        if len(lines) > 11:
            read_recording(folder / "rec.csv")  # what was kept is a readable recording
    resume = ["--resume"] if (folder / "rec.progress.json").is_file() else []
    if not resume and (folder / "rec.csv").exists():
        return f"a recording without a progress file after {delay_s:.2f} s"
    done = _spacecal(*argv, *resume, cwd=folder)
    if done.returncode != 0:
        return (
            f"acquire {' '.join(resume)} after {delay_s:.2f} s: exit {done.returncode}: {done.stderr[-800:]}"
        )
    lines = (folder / "rec.csv").read_text().splitlines()
    if header is not None and lines[0] != header:
        return "the resumed recording changed its columns"
    recording = read_recording(folder / "rec.csv")
    if not np.all(np.diff(recording.time_s) > 0):
        return "time not increasing after the resume point"
    try:
        app.calibrate(app.CalibrateSettings(str(folder / "rec.csv"), str(folder / "cal.json"), "ml"))
    except SpacecalError as exc:
        return f"calibrate after {delay_s:.2f} s: {exc}"
    return None


def _interruption_points() -> list[tuple[int, float]]:
    """The seeded signals and their times after the start, one in each slice of 1-7 s."""
    rng = random.Random(SEED)
    slice_s = 6.0 / POINTS
    return [
        (signal.SIGINT if k % 2 == 0 else signal.SIGTERM, 1.0 + slice_s * (k + rng.random()))
        for k in range(POINTS)
    ]


@pytest.mark.parametrize("point", range(POINTS))
def test_interrupted_acquisitions_resume_into_recordings_that_calibrate(tmp_path, point):
    """One case per point, so the test workers share them (each is a whole acquisition)."""
    signum, delay_s = _interruption_points()[point]
    problem = _interrupt_then_resume(tmp_path / "run", signum, delay_s)
    assert problem is None, problem


def _stop_samples() -> list[int]:
    """One seeded sample in each of POINTS equal parts of the plan."""
    rng = random.Random(SEED + 1)
    part_samples = PLAN_SAMPLES // POINTS
    return [1 + part_samples * part + rng.randrange(part_samples) for part in range(POINTS)]


@pytest.mark.parametrize("stop_at", _stop_samples())
def test_ctrl_c_at_random_samples_then_resume(tmp_path, stop_at):
    """The same, in this process: KeyboardInterrupt raised at seeded random samples (a test
    hook on the progress callback), so every part of the plan is hit whatever the machine's
    speed (one case per point, so the test workers share them)."""
    output = tmp_path / "rec.csv"

    def hook(samples, visible, move, label):
        if samples == stop_at:
            raise KeyboardInterrupt

    try:
        app.acquire(app.AcquireSettings(str(output), scenario="paper-white"), on_sample=hook)
    except SpacecalError as exc:
        assert "interrupted" in str(exc)
    app.acquire(app.AcquireSettings(str(output), scenario="paper-white", resume=True))
    recording = read_recording(output)
    assert np.all(np.diff(recording.time_s) > 0), f"stopped at sample {stop_at}"
    app.calibrate(app.CalibrateSettings(str(output), str(tmp_path / "cal.json"), "ml"))
