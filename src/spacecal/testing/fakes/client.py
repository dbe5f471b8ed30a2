"""Test-side handle on a fake world process: start it, talk to its control port, stop it."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import time

import numpy as np

#: The world process's module, run with ``python -m``.
WORLD = "spacecal.testing.fakes.world"


class WorldProcess:
    """A running fake world (see ``world.py``)."""

    def __init__(self, *arguments: str, ready_timeout_s: float = 20.0, niceness: int | None = None):
        """Start a world with ``arguments`` (``world.py``'s options), at ``niceness`` if given
        (where the caller may raise it), whatever the priority of the thread starting it."""
        priority = () if niceness is None else ("--niceness", str(niceness))
        self.process = subprocess.Popen(
            [sys.executable, "-m", WORLD, *arguments, *priority],
            stdout=subprocess.PIPE,
            stdin=subprocess.PIPE,
            text=True,
        )
        deadline = time.monotonic() + ready_timeout_s
        line = ""
        output = self.process.stdout
        assert output is not None  # stdout=PIPE
        while time.monotonic() < deadline:
            line = output.readline()
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
