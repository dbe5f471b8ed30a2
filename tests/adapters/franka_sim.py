"""The Franka protocol simulator the Franka adapter is tested against: ``franka-sim`` (PyPI,
Apache-2.0), a MuJoCo FR3 behind libfranka's wire protocol (robot server version 10).

It pins numpy 1.26 and so lives in a virtual environment of its own, found at
``$SPACECAL_FRANKA_SIM_ENV`` (default ``.simenv`` in the repository; created by
``python3 -m venv .simenv && .simenv/bin/pip install franka-sim franky-sim``). In CI
(``CI=true``) a missing simulator fails these tests instead of skipping them. Its FR3 model comes
from ``$FR3_MJCF`` or, offline, the MJCF that ``franky-sim`` ships (the simulator's own
default downloads MuJoCo Menagerie on first use). libfranka connects to port 1337 only and
the simulator binds it on every address, so one simulator runs at a time on the machine
(:data:`LOCK`).
"""

from __future__ import annotations

import contextlib
import fcntl
import glob
import os
import signal
import socket
import subprocess
import tempfile
import time
from pathlib import Path

import pytest

SIM_ENV = Path(
    os.environ.get("SPACECAL_FRANKA_SIM_ENV", str(Path(__file__).resolve().parents[2] / ".simenv"))
)
SERVER = SIM_ENV / "bin" / "run-franka-sim-server"
#: The whole machine's lock for port 1337.
LOCK = Path(tempfile.gettempdir()) / "spacecal-franka-sim-1337.lock"
#: The simulator answers within a second on a quiet machine (MuJoCo model build included).
STARTED_WITHIN_S = 30.0
HOST = "127.0.0.1"
#: What the simulator logs once it accepts a client.
READY = "Server ready for new client connection"


def unavailable(reason: str):
    if os.environ.get("CI") == "true":
        pytest.fail(f"the Franka simulator is not available in CI: {reason}")
    pytest.skip(reason)


def fr3_mjcf(workdir: Path) -> Path:
    """``$FR3_MJCF``, else franky-sim's FR3 MJCF laid out as it names its meshes (``assets/``)."""
    given = os.environ.get("FR3_MJCF")
    if given:
        return Path(given)
    packages = SIM_ENV / "lib" / "python3*" / "site-packages"
    found = glob.glob(str(packages / "franky_sim" / "assets" / "fr3.xml"))
    if not found:
        unavailable(f"no FR3 model for the simulator: set FR3_MJCF or install franky-sim into {SIM_ENV}")
    source = Path(found[0])
    (workdir / "assets").symlink_to(source.parent / "meshes")
    model = workdir / "fr3.xml"
    model.write_text(source.read_text())
    return model


def _answers(port: int = 1337) -> bool:
    with contextlib.suppress(OSError), socket.create_connection((HOST, port), timeout=0.2):
        return True
    return False


class FrankaSim:
    """One simulator process (its own process group, so a kill ends all of it)."""

    def __init__(self, workdir: Path, *options: str):
        if not SERVER.exists():
            unavailable(f"the Franka simulator is not installed ({SERVER} missing)")
        env = dict(os.environ, FR3_MJCF=str(fr3_mjcf(workdir)))
        self._lock = open(LOCK, "w")
        fcntl.flock(self._lock, fcntl.LOCK_EX)
        if _answers():
            self._release()
            pytest.skip("another program holds port 1337 (a robot or simulator already runs here)")
        self.log = workdir / "franka-sim.log"
        self.process = subprocess.Popen(
            [str(SERVER), "--no-gripper", *options],
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=open(self.log, "w"),
            start_new_session=True,
        )
        # ready when it says so: it takes one client at a time, and a probe connection would be
        # one it must first see gone (a second or more on a loaded machine)
        deadline = time.monotonic() + STARTED_WITHIN_S
        while READY not in self.log.read_text():
            if self.process.poll() is not None or time.monotonic() > deadline:
                text = self.log.read_text()[-2000:]
                self.stop()
                raise AssertionError(f"the Franka simulator did not start:\n{text}")
            time.sleep(0.1)

    def kill(self) -> None:
        """End it at once, as a switched-off robot or a pulled cable (no goodbye)."""
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.process.pid, signal.SIGKILL)
        self.process.wait(timeout=10)

    def stop(self) -> None:
        if self.process.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self.process.pid, signal.SIGTERM)
            try:
                self.process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.kill()
        self._release()

    def _release(self) -> None:
        if not self._lock.closed:
            fcntl.flock(self._lock, fcntl.LOCK_UN)
            self._lock.close()
