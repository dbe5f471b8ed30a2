"""Helpers of the UR controller tests: a fake world per controller generation, ``spacecal``
in a subprocess against it, and what the fake controller says afterwards."""

from __future__ import annotations

import itertools
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

from spacecal.estimators.time_offset import LARGEST_GAP_PERIODS, LARGEST_GAP_S
from spacecal.io.csv_core import metadata_path
from spacecal.io.raw_streams import ARRIVAL_COLUMN, read_raw_recording, stream_paths
from spacecal.testing.fakes.client import WorldProcess

from .loopback import NETWORK as _NETWORK

SPACECAL = [sys.executable, "-m", "spacecal"]
#: Loopback addresses of these worlds: the conftest's network, last octets from 200 up (the
#: conftest's own worlds count up from 1), so the two never collide in one process.
_addresses = itertools.count(200)
#: Scheduling niceness of a hardware test, of the processes it starts and of its fake worlds
#: (also those a module-scoped fixture starts before the test raises its own priority). At the
#: robot, spacecal's poller and the devices have the machine to themselves; a test of how a
#: run stops must not instead measure how busy the test machine is (at load 4-5 on 2 cores,
#: runs at equal priority were stopped as "UR state is stale"). Raised only where the runner
#: may (as root in CI); elsewhere left as it is.
HARDWARE_TEST_NICENESS = -10
#: The nominal model each fake generation runs (:data:`spacecal.testing.fakes.rtde.GENERATIONS`).
ROBOT_MODEL = {"cb3": "UR10", "eseries": "UR10e"}


def ur_world(generation: str = "cb3", *options: str) -> WorldProcess:
    address = next(_addresses)
    if address > 254:
        raise RuntimeError("out of loopback addresses for UR worlds")
    return WorldProcess(
        "--host",
        f"127.{_NETWORK}.0.{address}",
        "--ur-generation",
        generation,
        *options,
        niceness=HARDWARE_TEST_NICENESS,
    )


def stats(world: WorldProcess) -> dict:
    return json.loads(world.control("ur stats"))


def tracker_url(world: WorldProcess) -> str:
    return f"ndi://{world.info['host']}:{world.info['ndi_port']}"


def acquire_argv(
    world: WorldProcess,
    generation: str,
    output: Path,
    rom: Path,
    *extra: str,
    rotation_deg: str = "10",
    translation_mm: str = "100",
    brisk: bool = True,
) -> list[str]:
    return [
        *SPACECAL,
        "acquire",
        "--robot",
        f"ur://{world.info['host']}",
        "--tracker",
        tracker_url(world),
        "--rom",
        str(rom),
        "-o",
        str(output),
        "--robot-model",
        ROBOT_MODEL[generation],
        "--confirm-robot-motion",
        "--rotation-deg",
        rotation_deg,
        "--translation-mm",
        translation_mm,
        # brisk, so each run is short: the smallest sweeps the planner takes, at a fast pace
        *(["--speed-mm-s", "400", "--accel-mm-s2", "2000", "--angular-speed-deg-s", "120"] if brisk else []),
        *extra,
    ]


def run(argv: list[str], timeout_s: float = 120.0) -> subprocess.CompletedProcess:
    """Run ``argv``; past ``timeout_s`` the child dumps every thread's stack (faulthandler on
    SIGABRT) and the test fails with where it hung, not only that it did."""
    env = {**os.environ, "PYTHONFAULTHANDLER": "1"}
    with subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env) as child:
        try:
            stdout, stderr = child.communicate(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            child.send_signal(signal.SIGABRT)
            try:
                _, stderr = child.communicate(timeout=10)
            except subprocess.TimeoutExpired:
                child.kill()
                _, stderr = child.communicate()
            raise AssertionError(
                f"{' '.join(argv[2:4])} did not end within {timeout_s:.0f} s; its threads:\n{stderr[-6000:]}"
            ) from None
    return subprocess.CompletedProcess(argv, child.returncode, stdout, stderr)


def last_line(text: str) -> str:
    lines = text.strip().splitlines()
    return lines[-1] if lines else ""


def recorded_rows(recording: Path) -> int:
    """Frames written so far: ``acquire`` writes the raw tracker stream frame by frame (the
    paired ``rec.csv`` is derived from the streams when the run ends)."""
    stream = recording.with_name(recording.stem + ".tracker.csv")
    return stream.read_bytes().count(b"\n") if stream.is_file() else 0


def _complete_lines(path: Path) -> list[str]:
    """The rows of a stream being written, without its header and any partly written last row."""
    if not path.is_file():
        return []
    text = path.read_text()
    return text[: text.rfind("\n") + 1].splitlines()


def outside_the_robot_stream(robot_time_s: np.ndarray, time_s: np.ndarray) -> np.ndarray:
    """Whether each time (on the robot's clock, s) falls outside the robot stream or into a gap
    of it: the rule by which ``estimators.time_offset.pair_streams`` leaves a frame unpaired."""
    after = np.searchsorted(robot_time_s, time_s)
    outside = (after == 0) | (after == len(robot_time_s))
    inside = np.clip(after, 1, len(robot_time_s) - 1)
    largest = max(LARGEST_GAP_PERIODS * float(np.median(np.diff(robot_time_s))), LARGEST_GAP_S)
    return outside | (robot_time_s[inside] - robot_time_s[inside - 1] > largest)


def dropped_by_the_pairing_rule(raw, offset_s, frame_time_s):
    """Whether each frame, moved onto the robot's clock by ``offset_s``, falls outside the robot
    stream or into a gap of it (the frames :func:`pair_streams` may not pair).

    A stopped run is paired at the offset its few frames show; the resumed run at the offset
    the whole run shows, which may differ by tens of milliseconds on a loaded machine. A kept
    frame may then land before the robot's first state, in the stretch the stop left, or in a
    few ticks a loaded poller missed: it is still in the raw stream, but not paired.
    """
    return outside_the_robot_stream(raw.robot_time_s, frame_time_s + offset_s)


def assert_every_pairable_frame_kept(recording, kept):
    """The stopped run's paired recording holds every frame the pairing rule admits at the
    offset it was paired with, and only frames of the raw stream: nothing recorded that could
    be paired is lost. How many that is depends on how much of the robot's stream a loaded
    machine kept (its poller misses stretches), not on spacecal; at least one."""
    robot_stream, tracker_stream, _ = stream_paths(recording.with_suffix(""))
    raw = read_raw_recording(robot_stream, tracker_stream)
    offset_s = json.loads(metadata_path(recording).read_text())["pairing"]["offset_s"]
    assert len(kept) >= 1 and np.all(np.isin(kept, raw.tracker_time_s))
    left_out = raw.tracker_time_s[~np.isin(raw.tracker_time_s, kept)]
    assert np.all(dropped_by_the_pairing_rule(raw, offset_s, left_out)), left_out


def paired_times(recording):
    """``time_s`` of the paired recording a stopped run wrote, without the reader's floor of
    samples worth calibrating from: the fake e-Series's 500 Hz stream falls behind in motion on
    a busy machine, the pairing leaves out frames in its gaps, and a run stopped after 40 frames
    may keep fewer than ten pairs. What is kept must be intact; how much is the raw streams'
    (every frame, checked below)."""
    lines = recording.read_text().splitlines()
    column = lines[0].split(",").index("time_s")
    times = np.array([float(line.split(",")[column]) for line in lines[1:]])
    assert np.all(np.isfinite(times)) and np.all(np.diff(times) > 0)
    return times


def pairable_rows(recording: Path) -> int:
    """Tracker frames written so far that arrived inside the robot stream written so far, not in
    a gap of it (the pairing's rule, ``estimators.time_offset.pair_streams``, at the offset the
    arrivals show).

    The raw robot stream is the controller's ticks as a poller saw them; on a busy machine it
    misses stretches, and frames in them are not paired. A stop test needs paired frames to
    check, so it stops the run once there are some, not after a number of tracker rows alone.
    """
    robot = _complete_lines(recording.with_name(recording.stem + ".robot.csv"))[1:]
    tracker = _complete_lines(recording.with_name(recording.stem + ".tracker.csv"))
    if len(robot) < 2 or len(tracker) < 2:
        return 0
    robot_t = np.array([float(line.split(",", 1)[0]) for line in robot])
    column = tracker[0].split(",").index(ARRIVAL_COLUMN)
    cells = [line.split(",")[column] for line in tracker[1:]]
    arrival = np.array([float(cell) for cell in cells if cell])
    return int(np.sum(~outside_the_robot_stream(robot_t, arrival)))


#: The move (1-based, of the fake controller's commands) from which a stop test stops the run
#: with whatever it has recorded: the brisk plan has 18 moves, so this is its second half.
LATE_MOVE = 10


def moves_started(world) -> int:
    """Moves the fake controller has been commanded so far."""
    return len(stats(world)["commands"])


def wait_for_rows(
    recording: Path,
    rows: int,
    process=None,
    timeout_s: float = 90.0,
    pairable: int = 0,
    world=None,
    late_move: int = LATE_MOVE,
) -> None:
    """Wait until the run has written more than ``rows`` tracker frames, ``pairable`` of them
    inside the robot stream (see :func:`pairable_rows`), or ``process`` ended, or ``timeout_s``
    passed.

    Given the fake ``world``, also stop waiting once the robot has begun move ``late_move``
    with at least one pairable frame written: a starved machine polls the tracker at a
    fraction of its rate (a whole brisk run once wrote 33 frames), and a stop test must still
    stop the run in the middle, with something recorded to keep.
    """
    deadline = time.monotonic() + timeout_s
    next_look = 0.0
    while time.monotonic() < deadline:
        written = recorded_rows(recording)
        if written > rows and (not pairable or pairable_rows(recording) >= pairable):
            return
        if world is not None and written > 1 and time.monotonic() >= next_look:
            next_look = time.monotonic() + 0.1
            if moves_started(world) >= late_move and pairable_rows(recording) >= 1:
                return
        if process is not None and process.poll() is not None:
            return
        time.sleep(0.02)


class WhenRecorded(threading.Thread):
    """Send a world command once the run has written ``rows`` samples, ``pairable`` of them
    inside the robot stream, or (``late_move``) once the robot has begun that move with
    something pairable written (:func:`wait_for_rows`); ``sent_at`` is when the world
    acknowledged it (``time.monotonic``)."""

    def __init__(
        self,
        world: WorldProcess,
        command: str,
        recording: Path,
        rows: int = 20,
        timeout_s: float = 90.0,
        pairable: int = 0,
        late_move: int | None = LATE_MOVE,
    ):
        super().__init__(daemon=True)
        self.world, self.command, self.recording = world, command, recording
        self.rows, self.timeout_s, self.pairable = rows, timeout_s, pairable
        self.late_move = late_move
        self.sent_at: float | None = None
        self.reply = ""
        self.start()

    def run(self) -> None:
        wait_for_rows(
            self.recording,
            self.rows,
            timeout_s=self.timeout_s,
            pairable=self.pairable,
            world=self.world if self.late_move is not None else None,
            late_move=self.late_move or LATE_MOVE,
        )
        self.reply = self.world.control(self.command)
        self.sent_at = time.monotonic()


def assert_everything_closed(world: WorldProcess, timeout_s: float = 3.0) -> dict:
    """Every controller connection closed and the tracker no longer tracking (the fake's view)."""
    deadline = time.monotonic() + timeout_s
    while True:
        now = stats(world)
        closed = not any(now["connections"].values()) and not now["tracker_tracking"]
        if closed or time.monotonic() > deadline:
            break
        time.sleep(0.05)
    assert closed, now
    return now
