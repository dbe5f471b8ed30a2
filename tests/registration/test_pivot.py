"""Pivot calibration, against scikit-surgerycalibration's published results on real NDI data."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from spacecal.core.errors import DegenerateDataError, InvalidInputError, UnknownMethodError
from spacecal.geometry.transforms import make_transform
from spacecal.io.pose_files import read_matrix_folder
from spacecal.registration.pivot import pivot_calibration

from ..conftest import shared_realdata

# ../shared/realdata/pivot_sksurgery_ndi/README.md, tables A and B
REFERENCE = {
    ("subset57", "aos"): {
        "tip": [-14.473229, 394.634445, -7.406559],
        "pivot": [-804.741804, -85.474476, -2112.131173],
        "residual": 1.760678,
        "rms": 3.049584,
    },
    ("subset57", "sphere"): {
        "tip": [-16.792886, 382.776975, -7.256793],
        "pivot": [-792.976699, -81.898161, -2110.716614],
        "residual": 2.345629,
        "rms": 4.062748,
    },
    ("full", "aos"): {
        "tip": [-14.476172, 395.142822, -7.557904],
        "pivot": [-805.284736, -85.447793, -2112.066437],
        "residual": 1.838466,
        "rms": 3.184317,
    },
    ("full", "sphere"): {
        "tip": [-16.653391, 382.309321, -7.278931],
        "pivot": [-792.502588, -81.897600, -2110.659920],
        "residual": 2.489209,
        "rms": 4.311437,
    },
}


@pytest.fixture(scope="module")
def pivot_sets():
    folder = shared_realdata("pivot_sksurgery_ndi")
    subset = (folder / "subset57_sksurgerycalibration.txt").read_text().split()
    return {
        "subset57": read_matrix_folder(folder / "PivotCalibration", subset),
        "full": read_matrix_folder(folder / "PivotCalibration"),
    }


@pytest.mark.parametrize("data,method", sorted(REFERENCE))
def test_real_pivot_recording_reproduces_the_reference(pivot_sets, data, method):
    poses = pivot_sets[data]
    assert len(poses) == {"subset57": 57, "full": 1151}[data]
    result = pivot_calibration(poses, method)
    reference = REFERENCE[(data, method)]
    assert np.allclose(result.tip_in_marker, reference["tip"], atol=0.01)
    assert np.allclose(result.pivot_in_tracker, reference["pivot"], atol=0.01)
    # scikit-surgerycalibration's residual is the per-axis RMS = 3-D RMS / sqrt(3)
    assert result.rms_per_axis_mm == pytest.approx(reference["residual"], abs=1e-4)
    assert result.rms_mm == pytest.approx(reference["rms"], abs=1e-4)


def test_synthetic_pivot_is_exact():
    tip = np.array([1.0, 2.0, 150.0])
    pivot = np.array([10.0, -20.0, -1500.0])
    rotations = Rotation.from_rotvec(np.random.default_rng(0).normal(scale=0.4, size=(30, 3))).as_matrix()
    poses = make_transform(rotations, pivot - rotations @ tip)
    for method in ("aos", "sphere"):
        result = pivot_calibration(poses, method)
        assert np.allclose(result.tip_in_marker, tip, atol=1e-8)
        assert np.allclose(result.pivot_in_tracker, pivot, atol=1e-8)


def test_a_pivot_in_metres_is_refused_not_fitted():
    """The same pivot with its lengths in metres fits just as well, with a tip and residuals a
    thousand times too small: it is refused by where the marker is, never fitted."""
    tip = np.array([1.0, 2.0, 150.0])
    pivot = np.array([10.0, -20.0, -1500.0])
    rotations = Rotation.from_rotvec(np.random.default_rng(0).normal(scale=0.4, size=(30, 3))).as_matrix()
    poses = make_transform(rotations, pivot - rotations @ tip)
    poses[:, :3, 3] /= 1000.0
    for method in ("aos", "sphere"):
        with pytest.raises(InvalidInputError, match="look like metres"):
            pivot_calibration(poses, method)


def test_degenerate_pivots_are_refused():
    still = np.tile(np.eye(4), (10, 1, 1))
    still[:, :3, 3] = [10.0, -20.0, -1500.0]  # where a tracker sees a marker
    with pytest.raises(DegenerateDataError, match="did not rotate"):
        pivot_calibration(still, "aos")
    with pytest.raises(DegenerateDataError, match="at least 4"):
        pivot_calibration(still[:2], "aos")
    with pytest.raises(UnknownMethodError, match="aos, sphere"):
        pivot_calibration(still, "magic")


def test_malformed_pivot_poses_are_refused_and_missing_frames_skipped():
    tip = np.array([1.0, 2.0, 150.0])
    rotations = Rotation.from_rotvec(np.random.default_rng(1).normal(scale=0.4, size=(12, 3))).as_matrix()
    poses = make_transform(rotations, -rotations @ tip)
    poses[5] = np.nan  # the marker was not seen in frame 5
    assert np.allclose(pivot_calibration(poses, "aos").tip_in_marker, tip, atol=1e-8)
    scaled = poses.copy()
    scaled[2, :3, :3] *= 1.01
    with pytest.raises(
        InvalidInputError, match="tracker_from_marker_stack .*matrix 2: rotation block is not orthonormal"
    ):
        pivot_calibration(scaled, "aos")
    with pytest.raises(InvalidInputError, match=r"expected shape \(N, 4, 4\), got \(12, 3, 4\)"):
        pivot_calibration(poses[:, :3], "aos")


def test_the_fit_covariance_predicts_the_tip_scatter_of_white_noise():
    """Over 400 pivots of white position noise the tip's scatter per axis is what the fit's
    covariance says (the variance of 400 draws is known to +-7 %; 3.5 standard errors allowed)."""
    rng = np.random.default_rng(5)
    tip, pivot, noise_mm = np.array([3.0, -5.0, 160.0]), np.array([10.0, 20.0, -1500.0]), 0.25
    tips, predicted = [], []
    for _ in range(400):
        rotations = Rotation.from_rotvec(rng.normal(size=(60, 3)) * 0.3).as_matrix()
        translations = pivot - rotations @ tip + rng.normal(0.0, noise_mm, (60, 3))
        result = pivot_calibration(np.stack([make_transform(r, t) for r, t in zip(rotations, translations)]))
        tips.append(result.tip_in_marker)
        predicted.append(np.diag(result.tip_covariance_mm2))
    ratio = np.var(np.array(tips) - tip, axis=0) / np.mean(predicted, axis=0)
    assert np.all(np.abs(ratio - 1.0) < 3.5 * np.sqrt(2.0 / 400)), ratio


def test_a_pivot_file_keeps_the_tip_covariance(tmp_path):
    from spacecal.records import PivotResult

    rng = np.random.default_rng(1)
    rotations = Rotation.from_rotvec(rng.normal(size=(30, 3)) * 0.3).as_matrix()
    poses = np.stack([make_transform(r, [0.0, 0.0, -1000.0] - r @ [0.0, 0.0, 150.0]) for r in rotations])
    poses[:, :3, 3] += rng.normal(0.0, 0.1, (30, 3))
    result = pivot_calibration(poses)
    again = PivotResult.from_dict(result.to_dict())
    assert np.allclose(again.tip_covariance_mm2, result.tip_covariance_mm2)
    older = {k: v for k, v in result.to_dict().items() if k != "tip_covariance_mm2"}
    assert PivotResult.from_dict(older).tip_covariance_mm2 is None
