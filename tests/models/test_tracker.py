import numpy as np

from spacecal.geometry.transforms import axis_angle_transform, make_transform
from spacecal.models.marker import ndi_8700339_like
from spacecal.models.tracker import PyramidVolume, TrackerModel, view_angles_rad


def test_volume_is_along_negative_z_and_widens_with_depth():
    volume = PyramidVolume()
    assert volume.contains([[0, 0, -900]])[0]
    assert not volume.contains([[0, 0, 900]])[0]
    assert not volume.contains([[0, 0, -400]])[0] and not volume.contains([[0, 0, -1400]])[0]
    assert volume.contains([[440, 0, -1300]])[0] and not volume.contains([[440, 0, -700]])[0]


def test_marker_turning_away_is_lost():
    tracker = TrackerModel(max_view_angle_deg=70.0)
    marker = ndi_8700339_like()
    # marker x (face normal) points back at the sensor (+z in tracker) when facing it
    facing = make_transform(axis_angle_transform([0, 1, 0], -np.pi / 2)[:3, :3], [0, 0, -900])
    assert np.degrees(view_angles_rad(facing[None], marker.face_normal_in_marker))[0] < 1e-6
    turned = facing @ axis_angle_transform([0, 0, 1], np.radians(75))
    assert tracker.visible(facing[None], marker.spheres_in_marker, marker.face_normal_in_marker)[0]
    assert not tracker.visible(turned[None], marker.spheres_in_marker, marker.face_normal_in_marker)[0]
