"""Adapter tests: real client libraries against protocol fakes in a separate world process.

The pybind11 clients can block while holding the GIL, where pytest-level timeouts cannot fire,
so every test runs under a C-level watchdog (faulthandler) that ends a hung run.
"""

import faulthandler
import fcntl
import itertools
import os
import tempfile
import time
from pathlib import Path

import pytest

from spacecal.io.ndi_rom import rom_bytes
from spacecal.models.marker import ndi_8700339_like
from spacecal.testing.fakes.client import WorldProcess

from .loopback import NETWORK as _NETWORK
from .ur_runs import HARDWARE_TEST_NICENESS

#: Longer than any test's own subprocess timeouts, so those report first; the dump goes to a
#: file (pytest captures stderr), one per test worker, that .ci/run prints when the suite fails.
WATCHDOG_S = 400
WATCHDOG_LOG = os.path.join(
    os.environ.get("TMPDIR", "/tmp"), f"spacecal-watchdog-{os.environ.get('PYTEST_XDIST_WORKER', 'main')}.log"
)
#: The UR fake needs fixed ports, so every world gets its own loopback address (see loopback.py).
_addresses = itertools.count(1)


#: Hardware tests run at once, across the test workers of one run. They keep real-time
#: deadlines at a raised priority (below); more of them side by side than the machine has
#: cores would starve one another, whatever the other workers do.
HARDWARE_LANES = 2
_LANES = (
    Path(tempfile.gettempdir())
    / f"spacecal-hardware-lanes-{os.environ.get('PYTEST_XDIST_TESTRUNUID', os.getpid())}"
)


def _real_time(request) -> bool:
    """True for a test marked ``realtime`` (it runs protocol fakes on real time); the others here
    (URL tables, reply parsers) take no lane and keep their priority."""
    return request.node.get_closest_marker("realtime") is not None


@pytest.fixture(autouse=True)
def hardware_lane(request):
    """Hold one of :data:`HARDWARE_LANES` lanes (a file lock) for a real-time test's whole run."""
    if not _real_time(request):
        yield
        return
    _LANES.mkdir(exist_ok=True)
    while True:
        for lane in range(HARDWARE_LANES):
            handle = open(_LANES / f"{lane}.lock", "w")
            try:
                fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                handle.close()
                continue
            try:
                yield
            finally:
                fcntl.flock(handle, fcntl.LOCK_UN)
                handle.close()
            return
        time.sleep(0.05)


@pytest.fixture(autouse=True)
def watchdog(request):
    with open(WATCHDOG_LOG, "w") as log:
        log.write(f"watchdog armed for {request.node.nodeid}\n")
        log.flush()
        faulthandler.dump_traceback_later(WATCHDOG_S, exit=True, file=log)
        yield
        faulthandler.cancel_dump_traceback_later()


@pytest.fixture(autouse=True)
def ahead_of_other_tests(request):
    """Run a real-time test, and what it starts, at :data:`~tests.adapters.ur_runs.HARDWARE_TEST_NICENESS`."""
    if not _real_time(request):
        yield
        return
    before = os.getpriority(os.PRIO_PROCESS, 0)
    try:
        os.setpriority(os.PRIO_PROCESS, 0, HARDWARE_TEST_NICENESS)
    except OSError:
        yield
        return
    try:
        yield
    finally:
        os.setpriority(os.PRIO_PROCESS, 0, before)


@pytest.fixture
def world():
    """A fresh fake world per test (faults are sticky), on its own loopback address."""
    process = WorldProcess("--host", f"127.{_NETWORK}.0.{next(_addresses)}", niceness=HARDWARE_TEST_NICENESS)
    yield process
    process.stop()


@pytest.fixture
def rom_file(tmp_path):
    path = tmp_path / "marker.rom"
    # a tool definition of the marker the fake world carries: the recording states its geometry
    path.write_bytes(rom_bytes(ndi_8700339_like().spheres_in_marker))
    return path


@pytest.fixture
def make_world():
    """Start fake worlds with extra options (``--ndi-generation vega``, ``--igtl-sender old``...);
    each on its own loopback address, all stopped after the test."""
    started = []

    def start(*options: str) -> WorldProcess:
        process = WorldProcess(
            "--host", f"127.{_NETWORK}.0.{next(_addresses)}", *options, niceness=HARDWARE_TEST_NICENESS
        )
        started.append(process)
        return process

    yield start
    for process in started:
        process.stop()
