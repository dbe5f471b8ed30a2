"""Image-to-tracker registration from fiducials touched with a pointer: exact recovery, FRE limit."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from spacecal.core.errors import DegenerateDataError, InvalidInputError
from spacecal.geometry.transforms import apply_transform, make_transform
from spacecal.registration.image_fiducials import register_image_fiducials
from spacecal.registration.points import predicted_tre

TRACKER_FROM_IMAGE = make_transform(
    Rotation.from_rotvec([0.3, 1.2, -0.5]).as_matrix(), [40.0, -120.0, -1450.0]
)
FIDUCIALS = {
    "F-1": np.array([-60.0, 20.0, 10.0]),
    "F-2": np.array([55.0, 30.0, -5.0]),
    "F-3": np.array([0.0, -70.0, 25.0]),
    "F-4": np.array([10.0, 15.0, 80.0]),
    "F-5": np.array([-30.0, -40.0, -60.0]),
}


def _touched(noise_mm=0.0, seed=3):
    rng = np.random.default_rng(seed)
    return {
        k: apply_transform(TRACKER_FROM_IMAGE, p) + rng.normal(0, noise_mm, 3) for k, p in FIDUCIALS.items()
    }


def test_noise_free_touches_recover_the_registration():
    registration = register_image_fiducials(FIDUCIALS, _touched(), image_frame="image_lps")
    assert np.allclose(registration.tracker_from_image, TRACKER_FROM_IMAGE, atol=1e-9)
    assert registration.name == "tracker_from_image_lps"
    assert registration.pointer.fre_rms_mm < 1e-9 and not registration.pointer.accepted_above_limit


def test_the_errors_are_the_paired_point_figures():
    registration = register_image_fiducials(FIDUCIALS, _touched(0.3), image_frame="image_lps")
    pointer = registration.pointer
    # 0.3 mm per axis is 0.52 mm RMS in 3-D; FRE^2 ~ FLE^2 (1 - 2/N), with 9 degrees of freedom
    assert 0.0 < pointer.fre_rms_mm < 3 * 0.3 * np.sqrt(3)
    # FLE from FRE (Fitzpatrick): FLE^2 = FRE^2 N / (N - 2)
    assert pointer.fle_rms_mm == pytest.approx(pointer.fre_rms_mm * np.sqrt(5 / 3))
    target = np.array([5.0, 5.0, 150.0])
    far = predicted_tre(pointer.fiducials_in_image, target, pointer.fle_rms_mm)[0]
    near = predicted_tre(
        pointer.fiducials_in_image, np.mean(list(FIDUCIALS.values()), axis=0), pointer.fle_rms_mm
    )[0]
    assert far > near  # TRE grows away from the fiducials' centroid


def test_untouched_fiducials_are_left_out_and_unknown_touches_refused():
    touched = _touched()
    del touched["F-5"]
    assert register_image_fiducials(FIDUCIALS, touched, image_frame="image_lps").pointer.labels == (
        "F-1",
        "F-2",
        "F-3",
        "F-4",
    )
    touched["F-9"] = np.zeros(3)
    with pytest.raises(InvalidInputError, match="'F-9' is not a fiducial of the image"):
        register_image_fiducials(FIDUCIALS, touched, image_frame="image_lps")
    with pytest.raises(DegenerateDataError, match="at least 3"):
        register_image_fiducials(
            FIDUCIALS, {k: _touched()[k] for k in ("F-1", "F-2")}, image_frame="image_lps"
        )


def test_an_fre_above_the_limit_is_refused_unless_accepted():
    touched = _touched()
    touched["F-3"] = touched["F-3"] + np.array([0.0, 6.0, 0.0])  # touched in the wrong divot
    with pytest.raises(
        InvalidInputError, match=r"FRE is .* above its limit 2 mm \(worst: .*--accept-high-fre"
    ) as caught:
        register_image_fiducials(FIDUCIALS, touched, image_frame="image_lps")
    assert "\n" not in str(caught.value)
    accepted = register_image_fiducials(FIDUCIALS, touched, image_frame="image_lps", accept_high_fre=True)
    assert accepted.pointer.accepted_above_limit and accepted.pointer.fre_rms_mm > 2.0
    # a looser limit takes it as it is
    loose = register_image_fiducials(FIDUCIALS, touched, image_frame="image_lps", max_fre_mm=10.0)
    assert not loose.pointer.accepted_above_limit


def test_a_tip_error_common_to_every_touch_is_carried_by_the_stated_tip_accuracy():
    """A pointer touched in one orientation moves every touch by its tip error: the FRE does
    not change, and the registration moves by it in full. Over many pointers whose tip errors
    are drawn with the stated RMS, the RMS error at a target is the quadrature sum the predicted
    TRE states."""
    from spacecal.registration.image_fiducials import pointer_predicted_tre

    fle, tip_rms, trials = 0.25, 0.3, 4000
    rng = np.random.default_rng(11)
    target = np.array([20.0, 10.0, 120.0])  # beyond the fiducials, where the TRE grows
    errors, fres, predicted = [], [], []
    for _ in range(trials):
        tip = rng.normal(0.0, tip_rms / np.sqrt(3.0), 3)  # 3-D RMS tip_rms, common to all touches
        touched = {
            k: apply_transform(TRACKER_FROM_IMAGE, p) + tip + rng.normal(0.0, fle / np.sqrt(3.0), 3)
            for k, p in FIDUCIALS.items()
        }
        registration = register_image_fiducials(
            FIDUCIALS, touched, image_frame="image_lps", tip_accuracy_mm=tip_rms
        )
        errors.append(
            np.linalg.norm(
                apply_transform(registration.tracker_from_image, target)
                - apply_transform(TRACKER_FROM_IMAGE, target)
            )
        )
        fres.append(registration.pointer.fre_rms_mm)
        predicted.append(pointer_predicted_tre(registration.pointer, target)[0])
    measured_rms = float(np.sqrt(np.mean(np.square(errors))))
    fitzpatrick = float(predicted_tre(np.array(list(FIDUCIALS.values())), target, fle)[0])
    expected = float(np.hypot(fitzpatrick, tip_rms))
    # 4000 trials: the RMS of a 3-D error is known to about 1/sqrt(2 * 4000 * 3) ~ 0.7 %
    assert measured_rms == pytest.approx(expected, rel=0.04)
    # Fitzpatrick's TRE alone would state too little: the tip term is what closes the gap
    assert measured_rms > 1.3 * fitzpatrick
    # the per-registration prediction (FLE from each FRE) agrees on average
    assert float(np.sqrt(np.mean(np.square(predicted)))) == pytest.approx(expected, rel=0.1)


def test_a_stated_tip_accuracy_out_of_range_is_refused_in_one_line():
    with pytest.raises(InvalidInputError, match="tip's accuracy") as caught:
        register_image_fiducials(FIDUCIALS, _touched(0.1), image_frame="image_lps", tip_accuracy_mm=-1.0)
    assert "\n" not in str(caught.value)
