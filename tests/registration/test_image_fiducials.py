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
