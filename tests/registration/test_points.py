"""Paired-point registration, FRE, predicted TRE; the real PLUS landmark recording."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from spacecal.core.errors import DegenerateDataError, InvalidInputError
from spacecal.geometry.rotations import rotation_angle
from spacecal.geometry.transforms import apply_transform, make_transform
from spacecal.io.plus_config import read_plus_landmarks, read_plus_transform
from spacecal.io.plus_sequence import read_plus_sequence
from spacecal.registration.landmarks import LandmarkDetectionSettings
from spacecal.registration.points import register_points
from spacecal.workflows.landmark_registration import register_landmarks_from_stylus

from ..conftest import shared_realdata

FIDUCIALS = np.array([[0, 0, 0], [80, 0, 0], [0, 60, 0], [0, 0, 50], [70, 50, 40], [30, 70, 10.0]])


def test_exact_points_register_exactly():
    truth = make_transform(Rotation.from_rotvec([0.3, -0.2, 0.5]).as_matrix(), [10, -20, 300])
    reg = register_points(points_in_source=FIDUCIALS, points_in_target=apply_transform(truth, FIDUCIALS))
    assert np.allclose(reg.target_from_source, truth, atol=1e-10) and reg.fre_rms_mm < 1e-10


def test_fle_and_predicted_tre_match_monte_carlo():
    # Fitzpatrick-West-Maurer: with isotropic FLE the predicted RMS TRE at a target matches simulation.
    rng = np.random.default_rng(0)
    fle_rms, target = 0.5, np.array([[150.0, 100.0, 80.0]])
    errors, fle_estimates, predicted = [], [], []
    for _ in range(2000):
        noisy = FIDUCIALS + rng.normal(scale=fle_rms / np.sqrt(3), size=FIDUCIALS.shape)
        reg = register_points(points_in_source=FIDUCIALS, points_in_target=noisy)
        errors.append(np.linalg.norm(apply_transform(reg.target_from_source, target) - target))
        fle_estimates.append(reg.fle_rms_mm**2)
        predicted.append(reg.predicted_tre_mm(target, fle_rms_mm=fle_rms)[0])
    observed = np.sqrt(np.mean(np.square(errors)))
    assert predicted[0] == pytest.approx(observed, rel=0.1)
    assert np.sqrt(np.mean(fle_estimates)) == pytest.approx(fle_rms, rel=0.05)


def test_degenerate_fiducials():
    with pytest.raises(DegenerateDataError, match="at least 3"):
        register_points(points_in_source=FIDUCIALS[:2], points_in_target=FIDUCIALS[:2])
    with pytest.raises(InvalidInputError, match=r"points_in_target: expected shape \(N, 3\), got \(6, 2\)"):
        register_points(points_in_source=FIDUCIALS, points_in_target=FIDUCIALS[:, :2])
    with pytest.raises(InvalidInputError, match="differ|source .* and target"):
        register_points(points_in_source=FIDUCIALS, points_in_target=FIDUCIALS[:5])
    touched = FIDUCIALS.copy()
    touched[4, 0] = np.nan
    with pytest.raises(InvalidInputError, match="points_in_target .*row 4: non-finite"):
        register_points(points_in_source=FIDUCIALS, points_in_target=touched)
    line = np.outer(np.arange(5.0), [1, 2, 3])
    with pytest.raises(DegenerateDataError, match="collinear"):
        register_points(points_in_source=line, points_in_target=line)


# ../shared/realdata/plus_phantom_landmarks/README.md: PLUS's baseline result
PLUS_REFERENCE_FROM_PHANTOM = np.array(
    [
        [-0.00479115, 0.00329566, -0.999983, 22.7064],
        [-0.0127965, 0.999912, 0.00335674, -39.7536],
        [0.999907, 0.0128124, -0.00474856, 25.6504],
        [0, 0, 0, 1],
    ]
)
PLUS_MEAN_ERROR_MM = 0.198046


@pytest.fixture(scope="module")
def plus_recording():
    folder = shared_realdata("plus_phantom_landmarks")
    sequence = read_plus_sequence(folder / "EightLandmarkPointsTrackedForPhantomRegistration.igs.mha")
    config = folder / "PlusDeviceSet_fCal_Sim_RecordPhantomLandmarks.xml"
    return sequence, read_plus_landmarks(config)[1], read_plus_transform(config, "StylusTip", "Stylus")


def register(plus_recording, plus_compatible):
    sequence, landmarks, stylus_from_tip = plus_recording
    settings = None
    if plus_compatible:
        times = sequence.timestamps_s
        settings = LandmarkDetectionSettings(
            acquisition_rate_hz=1 / (times[1] - times[0]), min_landmark_spacing_mm=15.0, plus_compatible=True
        )
    return register_landmarks_from_stylus(
        sequence.timestamps_s,
        sequence.transform("ReferenceToTracker"),
        sequence.transform("StylusToTracker"),
        stylus_from_tip,
        landmarks,
        settings,
    )


def test_real_landmark_recording_lands_within_0_1_mm_of_plus(plus_recording):
    result = register(plus_recording, plus_compatible=True)
    reg = result
    assert len(result.detected_in_reference) == 8
    position = np.linalg.norm(reg.reference_from_phantom[:3, 3] - PLUS_REFERENCE_FROM_PHANTOM[:3, 3])
    angle = np.degrees(
        rotation_angle(reg.reference_from_phantom[:3, :3] @ PLUS_REFERENCE_FROM_PHANTOM[:3, :3].T)
    )
    assert position < 0.1 and angle < 0.2  # PLUS's own test tolerances
    # PLUS's "Error" is the mean landmark distance; we report it beside the RMS
    assert reg.fre_mean_mm == pytest.approx(PLUS_MEAN_ERROR_MM, abs=0.02)
    assert reg.fre_rms_mm > reg.fre_mean_mm


def test_full_period_averaging_stays_close_to_plus(plus_recording):
    reg = register(plus_recording, plus_compatible=False)
    assert np.linalg.norm(reg.reference_from_phantom[:3, 3] - PLUS_REFERENCE_FROM_PHANTOM[:3, 3]) < 0.2
    assert reg.fre_mean_mm < 0.25


def test_landmark_touches_are_the_eight_dwell_periods(plus_recording):
    result = register(plus_recording, plus_compatible=True)
    start = plus_recording[0].timestamps_s[0]
    # the README's dwell periods (s from the start): 5.7, 12.0, 18.9, 24.7, 35.9, 42.2, 49.0, 56.0
    assert np.allclose(
        np.array(result.detected_at_s) - start, [5.7, 12.0, 18.9, 24.7, 35.9, 42.2, 49.0, 56.0], atol=1.5
    )


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ('<Landmark Name="#8"', '<Landmark Name="#1"', "'#1' is defined twice"),
        (
            '<Landmark Name="#8" Position="-34.3 45.0 0.0"',
            '<Landmark Name="#8" Position="104.3 5.0 20.4"',
            "'#1' and '#8' are 0.40 mm apart",
        ),
    ],
)
def test_a_phantom_with_a_landmark_given_twice_is_refused(tmp_path, old, new, message):
    """A name or a point given twice would pair one stylus touch with two landmarks."""
    config = shared_realdata("plus_phantom_landmarks") / "PlusDeviceSet_fCal_Sim_RecordPhantomLandmarks.xml"
    text = config.read_text()
    assert old in text
    path = tmp_path / "phantom.xml"
    path.write_text(text.replace(old, new))
    with pytest.raises(InvalidInputError, match=message):
        read_plus_landmarks(path)
