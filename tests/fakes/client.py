"""Test-side handle on a fake world process: start it, talk to its control port, stop it."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

WORLD = Path(__file__).with_name("world.py")


#: Scheduling priority of the fake devices' process (lower runs first). A real controller and
#: tracker run on their own processors: on a busy test machine the fakes must not be the ones
#: starved, or a test of spacecal's stale-state guard measures the machine's load instead.
FAKE_DEVICE_NICENESS = -10


def _ahead_of_other_work() -> None:
    """Raise the fake world's priority where the test runner may (as root); else leave it."""
    try:
        os.setpriority(os.PRIO_PROCESS, 0, FAKE_DEVICE_NICENESS)
    except (OSError, AttributeError):
        pass


class WorldProcess:
    """A running fake world (see ``world.py``)."""

    def __init__(self, *arguments: str, ready_timeout_s: float = 20.0):
        self.process = subprocess.Popen(
            [sys.executable, str(WORLD), *arguments],
            stdout=subprocess.PIPE,
            stdin=subprocess.PIPE,
            text=True,
            preexec_fn=_ahead_of_other_work,
        )
        deadline = time.monotonic() + ready_timeout_s
        line = ""
        while time.monotonic() < deadline:
            line = self.process.stdout.readline()
            if line.startswith("READY ") or not line:
                break
        if not line.startswith("READY "):
            self.process.kill()
            raise RuntimeError(f"fake world did not start (last output {line!r})")
        self.info = json.loads(line[len("READY ") :])

    def control(self, command: str) -> str:
        with socket.create_connection((self.info["host"], self.info["control_port"]), timeout=5) as sock:
            stream = sock.makefile("rw")
            stream.write(command + "\n")
            stream.flush()
            return stream.readline().strip()

    def truth(self) -> dict:
        data = json.loads(self.control("truth"))
        return {k: np.array(v) if k != "scenario" else v for k, v in data.items()}

    def stop(self) -> None:
        if self.process.poll() is None:
            try:
                self.control("quit")
                self.process.wait(timeout=5)
            except (OSError, subprocess.TimeoutExpired):
                self.process.kill()
