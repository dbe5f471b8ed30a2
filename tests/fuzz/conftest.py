"""The fuzz suite's profile and its shared base inputs.

``SPACECAL_FUZZ_PROFILE=fast`` (default, CI: a few minutes on two cores) or ``thorough``
(more cases per command and class; ``benchmarks/fuzz.py`` runs the full >= 2,000-case sweep).
"""

from __future__ import annotations

import os

import pytest

from spacecal.testing.fuzz import PROFILES, build_base


def profile() -> str:
    name = os.environ.get("SPACECAL_FUZZ_PROFILE", "fast")
    if name not in PROFILES:
        raise pytest.UsageError(f"SPACECAL_FUZZ_PROFILE must be one of {', '.join(PROFILES)}")
    return name


@pytest.fixture(scope="session")
def fuzz_base(tmp_path_factory):
    """Base inputs of every command: one simulated recording, its calibration and the rest."""
    return build_base(tmp_path_factory.mktemp("fuzz") / "base")
