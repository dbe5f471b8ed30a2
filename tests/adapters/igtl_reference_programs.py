"""Building the reference OpenIGTLink programs (``tests/igtl_reference``) on the OpenIGTLink C++
library (Debian package ``libopenigtlink-dev``, header version 1), for the tests that run them.

Outside CI a test skips when the library or a C++ compiler is missing; in CI (``CI=true``) that
is a failure, so the reference checks can never be skipped silently there.
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
from pathlib import Path

import pytest

SOURCES = Path(__file__).resolve().parents[1] / "igtl_reference"
INCLUDE = Path(os.environ.get("OPENIGTLINK_INCLUDE", "/usr/include/openigtlink"))


def unavailable(reason: str):
    if os.environ.get("CI") == "true":
        pytest.fail(f"OpenIGTLink reference programs cannot be built in CI: {reason}")
    pytest.skip(reason)


def build_reference_programs(out: Path, names: tuple[str, ...]) -> dict[str, Path]:
    """Compile ``tests/igtl_reference/<name>.cxx`` for each name into ``out``; name -> binary."""
    compiler = shutil.which("g++") or shutil.which("c++")
    if compiler is None:
        unavailable("no C++ compiler")
    if not (INCLUDE / "igtlTransformMessage.h").is_file():
        unavailable(f"the OpenIGTLink headers are not in {INCLUDE} (apt-get install libopenigtlink-dev)")
    programs = {}
    for name in names:
        binary = out / f"igtl_reference_{name}"
        build = subprocess.run(
            [compiler, "-O1", "-std=c++14", f"-I{INCLUDE}", str(SOURCES / f"{name}.cxx"), "-o", str(binary)]
            + ["-lOpenIGTLink"],
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert build.returncode == 0, build.stderr[-2000:]  # the library is here: a build error is a bug
        programs[name] = binary
    return programs


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]
