"""Adapter tests: real client libraries against protocol fakes in a separate world process.

The pybind11 clients can block while holding the GIL, where pytest-level timeouts cannot fire,
so every test runs under a C-level watchdog (faulthandler) that ends a hung run.
"""

import faulthandler
import itertools

import pytest

from ..fakes.client import WorldProcess

WATCHDOG_S = 120
_addresses = itertools.count(20)


@pytest.fixture(autouse=True)
def watchdog():
    faulthandler.dump_traceback_later(WATCHDOG_S, exit=True)
    yield
    faulthandler.cancel_dump_traceback_later()


@pytest.fixture
def world():
    """A fresh fake world per test (faults are sticky), on its own loopback address."""
    process = WorldProcess("--host", f"127.0.0.{next(_addresses)}")
    yield process
    process.stop()


@pytest.fixture
def rom_file(tmp_path):
    path = tmp_path / "marker.rom"
    path.write_bytes(b"passive marker definition for the fake tracker\n" + bytes(200))
    return path
