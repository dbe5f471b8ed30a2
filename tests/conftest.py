"""Shared, session-scoped simulations (each costs about two seconds, so build them once), the
guard of the ``realtime`` mark, and the disk probe of the tests that bound how fast a run ends."""

from __future__ import annotations

import dataclasses

import pytest
from hypothesis import HealthCheck, settings

from spacecal.experiments.simulation import simulate
from spacecal.io.recording_csv import write_recording
from spacecal.sim.scenario import PRESETS
from spacecal.testing.disk_probe import DiskProbe

# Property tests check values, not speed: on a busy machine an example that takes longer than
# hypothesis's 200 ms deadline, or slow data generation, is not a failure.
settings.register_profile("spacecal", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("spacecal")

#: No noise, no kinematic error, no dropouts: estimators must be exact (to ~1e-9).
NOISE_FREE = dataclasses.replace(
    PRESETS["paper-white"], name="noise-free", white_noise_rms_mm=0.0, dropout_probability=0.0
)


@pytest.fixture(autouse=True)
def realtime_mark_is_true(request, monkeypatch):
    """A test that starts a protocol-fake world (:class:`~spacecal.testing.fakes.client.
    WorldProcess`: real client libraries against fakes on real time) carries the ``realtime``
    mark, given in its module (``pytestmark = pytest.mark.realtime``) or on the test itself. The
    README's test command runs the marked tests apart from the rest (``-m realtime``), so their
    deadlines share a busy machine with nothing of the suite's own; an unmarked one fails here
    rather than run beside them."""
    if request.node.get_closest_marker("realtime") is not None:
        yield
        return
    from spacecal.testing.fakes.client import WorldProcess

    def refused(*_args, **_kwargs):
        raise AssertionError(
            f"{request.node.nodeid} starts a protocol-fake world on real time without the realtime "
            "mark: add pytestmark = pytest.mark.realtime to its module, or @pytest.mark.realtime"
        )

    monkeypatch.setattr(WorldProcess, "__init__", refused)
    yield


@pytest.fixture
def disk(tmp_path):
    """A :class:`~spacecal.testing.disk_probe.DiskProbe` beside the test: how long the disk
    stalled (a run's end waits through the stalls for its recordings' last syncs)."""
    probe = DiskProbe(tmp_path)
    yield probe
    probe.close()


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


#: Views in the Storz laparoscope hand-eye set.
STORZ_VIEWS = 10


def storz_handeye():
    """UCL's Storz laparoscope hand-eye set (../shared/realdata/handeye_storz_sksurgery) as a
    recording, with the authors' hand-eye (SmartLiver's ``calib.left.handeye.txt``).

    It maps onto ``tracker_from_marker_i = tracker_from_base @ base_from_tcp_i @ tcp_from_marker``
    with tracker = the camera, base = the laparoscope's marker, tcp = the board's marker and
    marker = the board pattern: ``base_from_tcp_i = inv(T_dev_i) @ T_obj_i``, ``tracker_from_marker_i
    = E_i`` (pattern -> camera, from the images); ``tracker_from_base`` is the hand-eye.
    """
    import numpy as np

    from spacecal.geometry.transforms import invert_transform
    from spacecal.records import Recording

    folder = shared_realdata("handeye_storz_sksurgery")

    def load(name: str) -> np.ndarray:
        return np.loadtxt(folder / name).reshape(4, 4)

    views = range(STORZ_VIEWS)
    device = np.array([load(f"tracking/calib.device_tracking.{i}.txt") for i in views])
    board = np.array([load(f"tracking/calib.calib_obj_tracking.{i}.txt") for i in views])
    camera = np.array(
        [load(f"derived_sksurgerycalibration_1.2.6/camera/calib.extrinsics.{i}.txt") for i in views]
    )
    recording = Recording(
        time_s=np.arange(float(STORZ_VIEWS)),
        segment=np.array(["view"] * STORZ_VIEWS),
        joints_rad=np.full((STORZ_VIEWS, 6), np.nan),
        base_from_tcp_stack=invert_transform(device) @ board,
        tracker_from_marker_stack=camera,
        marker_rms_mm=np.full(STORZ_VIEWS, np.nan),
        metadata={"source": "Storz hand-eye set"},
    )
    return recording, load("authors_reference/calib.left.handeye.txt")
