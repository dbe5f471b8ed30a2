"""The README's test command, which CI runs part by part (``.ci/run``): the hardware tests run
apart from the rest, and every one of them is in that part."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def readme_test_command() -> str:
    lines = (ROOT / "README.md").read_text().splitlines()
    return lines[lines.index(next(line for line in lines if line.startswith("# 2."))) + 1]


def test_the_readme_runs_the_real_time_tests_apart_from_the_rest():
    parts = readme_test_command().split(" && ")
    runs = [part for part in parts if " -m pytest " in part]
    assert len(runs) == 2, parts
    assert runs[0].endswith('-m "not realtime"') and runs[1].endswith("-m realtime"), runs


def collect(*arguments: str) -> subprocess.CompletedProcess:
    """``pytest --collect-only -q`` with ``arguments``, from the repository's root."""
    return subprocess.run(
        [sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider", *arguments],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_the_real_time_tests_are_those_that_run_on_real_time():
    """The mark is given by what a test does (``pytestmark`` in its module, or on the test):
    the station's runs on the protocol fakes and the stop tests are marked; the URL table's
    tests, which open nothing, are not. ``tests/conftest.py`` fails an unmarked test that
    starts a protocol-fake world."""
    unmarked = collect("-m", "not realtime", "tests/station/test_browser_fakes.py")
    assert unmarked.returncode == 5, unmarked.stdout[-2000:]  # 5: no tests collected
    marked = collect("-m", "realtime", "tests/adapters/test_ur_stops.py")
    assert marked.returncode == 0 and "test_each_stop_ends_the_run" in marked.stdout, marked.stdout[-2000:]
    parsing = collect("-m", "realtime", "tests/adapters/test_device_urls.py")
    assert parsing.returncode == 5, parsing.stdout[-2000:]


def test_an_unmarked_test_cannot_start_a_protocol_fake_world():
    from spacecal.testing.fakes.client import WorldProcess

    with pytest.raises(AssertionError, match="without the realtime mark"):
        WorldProcess("--host", "127.0.0.1")
