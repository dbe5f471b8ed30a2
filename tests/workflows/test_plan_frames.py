"""A needle plan brought to the tracker and the base: names must meet, LPS/RAS converted exactly."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from spacecal.core.errors import InvalidInputError
from spacecal.geometry.transforms import apply_transform, invert_transform, make_transform
from spacecal.records.needle_plan import ImageRegistration, NeedlePlan
from spacecal.workflows.plan_frames import locate_plan

TRACKER_FROM_IMAGE_LPS = make_transform(
    Rotation.from_rotvec([0.2, -0.4, 2.1]).as_matrix(), [-30.0, 80.0, -1400.0]
)
TRACKER_FROM_BASE = make_transform(
    Rotation.from_rotvec([1.0, 0.1, -0.3]).as_matrix(), [500.0, -200.0, -900.0]
)
LPS = np.diag([-1.0, -1.0, 1.0, 1.0])
PLAN = NeedlePlan(
    entry_in_image=[10.0, -20.0, 40.0], target_in_image=[25.0, 5.0, -30.0], image_frame="image_lps"
)


def test_a_registration_in_ras_gives_the_same_points_as_in_lps():
    in_lps = ImageRegistration(TRACKER_FROM_IMAGE_LPS, "image_lps")
    in_ras = ImageRegistration(TRACKER_FROM_IMAGE_LPS @ LPS, "image_ras")  # tracker_from_image_ras
    a, b = locate_plan(PLAN, in_lps), locate_plan(PLAN, in_ras)
    assert np.allclose(
        a.entry_in_tracker, apply_transform(TRACKER_FROM_IMAGE_LPS, PLAN.entry_in_image), atol=1e-12
    )
    assert np.allclose(a.entry_in_tracker, b.entry_in_tracker, atol=1e-12)
    assert np.allclose(a.target_in_tracker, b.target_in_tracker, atol=1e-12)


def test_base_coordinates_follow_the_calibration():
    located = locate_plan(PLAN, ImageRegistration(TRACKER_FROM_IMAGE_LPS, "image_lps"), TRACKER_FROM_BASE)
    base_from_image = invert_transform(TRACKER_FROM_BASE) @ TRACKER_FROM_IMAGE_LPS
    assert np.allclose(
        located.target_in_base, apply_transform(base_from_image, PLAN.target_in_image), atol=1e-9
    )
    length = np.linalg.norm(located.target_in_base - located.entry_in_base)
    assert length == pytest.approx(PLAN.length_mm, abs=1e-9)


def test_image_frames_that_disagree_are_refused():
    unstated = NeedlePlan(entry_in_image=[0, 0, 0], target_in_image=[0, 0, 50], image_frame="image")
    with pytest.raises(
        InvalidInputError, match="plan's points are in image but the registration is tracker_from_image_lps"
    ):
        locate_plan(unstated, ImageRegistration(TRACKER_FROM_IMAGE_LPS, "image_lps"))


def test_a_reference_registration_gives_no_base_coordinates():
    registration = ImageRegistration(TRACKER_FROM_IMAGE_LPS, "image_lps", tracker_frame="reference")
    assert locate_plan(PLAN, registration).entry_in_base is None
    with pytest.raises(InvalidInputError, match="reference_from_image_lps: robot-base coordinates need"):
        locate_plan(PLAN, registration, TRACKER_FROM_BASE)
