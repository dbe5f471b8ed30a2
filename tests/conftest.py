"""Shared, session-scoped simulations: each costs about two seconds, so build them once."""

from __future__ import annotations

import dataclasses

import pytest

from spacecal.experiments.simulation import simulate
from spacecal.io.recording_csv import write_recording
from spacecal.sim.scenario import PRESETS

#: No noise, no kinematic error, no dropouts: estimators must be exact (to ~1e-9).
NOISE_FREE = dataclasses.replace(
    PRESETS["paper-white"], name="noise-free", white_noise_rms_mm=0.0, dropout_probability=0.0
)


@pytest.fixture(scope="session")
def noise_free_simulation():
    return simulate(NOISE_FREE)


@pytest.fixture(scope="session")
def white_simulation():
    return simulate(PRESETS["paper-white"])


@pytest.fixture(scope="session")
def realistic_simulation():
    return simulate(PRESETS["paper-realistic"])


@pytest.fixture(scope="session")
def recording_file(tmp_path_factory, white_simulation):
    """A valid recording CSV (and metadata) on disk, simulated from the white-noise preset."""
    path = tmp_path_factory.mktemp("recording") / "recording.csv"
    write_recording(white_simulation.recording, path)
    return path


@pytest.fixture(scope="session")
def outlier_simulation():
    return simulate(PRESETS["paper-outliers"])


def shared_realdata(name: str):
    """Path of a real recording in ../shared/realdata (beside the clone), or skip.

    In CI (CI=true) a missing data set is a failure, not a skip: those tests are the ones
    that compare with other groups' published results.
    """
    import os
    from pathlib import Path

    path = Path(__file__).resolve().parents[1].parent / "shared" / "realdata" / name
    if not path.exists():
        if os.environ.get("CI") == "true":
            pytest.fail(f"real data set {path} is missing")
        pytest.skip(f"real data set {path} is not here")
    return path
