"""Exports read back: Slicer ITK transform files (with LPS/RAS), PLUS, and PLUS imports."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from spacecal.core.errors import InvalidInputError
from spacecal.geometry.transforms import make_transform
from spacecal.io.plus_import import recording_from_plus_sequence
from spacecal.io.recording_csv import read_recording, write_recording
from spacecal.io.slicer import read_slicer_transform, write_slicer_transform

TRACKER_FROM_BASE = make_transform(
    Rotation.from_rotvec([0.2, -1.1, 0.4]).as_matrix(), [-150.0, 320.0, -1450.0]
)


def test_slicer_file_follows_the_itk_format_and_reads_back(tmp_path):
    path = write_slicer_transform(TRACKER_FROM_BASE, tmp_path / "BaseToTracker.tfm")
    lines = path.read_text().splitlines()
    assert lines[0] == "#Insight Transform File V1.0" and lines[2] == "Transform: AffineTransform_double_3_3"
    parameters = np.array(lines[3].split(":")[1].split(), dtype=float)
    assert parameters.size == 12 and lines[4] == "FixedParameters: 0 0 0"
    assert np.allclose(read_slicer_transform(path), TRACKER_FROM_BASE, atol=1e-12)


def test_slicer_convention_is_lps_resampling():
    # A pure translation by +10 mm along RAS x is stored as the ITK (resampling) offset +10 in LPS x:
    # inverse (-10 RAS) then x negated (+10 LPS).
    import tempfile
    from pathlib import Path

    shift = make_transform(np.eye(3), [10.0, 20.0, 30.0])
    with tempfile.TemporaryDirectory() as folder:
        path = write_slicer_transform(shift, Path(folder) / "t.tfm")
        parameters = np.array(path.read_text().splitlines()[3].split(":")[1].split(), dtype=float)
    assert np.allclose(parameters[9:], [10.0, 20.0, -30.0])


def test_slicer_reader_honours_a_centre_of_rotation(tmp_path):
    path = tmp_path / "c.tfm"
    rotation = Rotation.from_rotvec([0, 0, 0.5]).as_matrix()
    centre = np.array([5.0, -3.0, 2.0])
    path.write_text(
        "#Insight Transform File V1.0\n#Transform 0\nTransform: AffineTransform_double_3_3\n"
        f"Parameters: {' '.join(map(str, rotation.ravel()))} 0 0 0\n"
        f"FixedParameters: {' '.join(map(str, centre))}\n"
    )
    itk = np.eye(4)
    itk[:3, :3] = rotation
    itk[:3, 3] = centre - rotation @ centre
    ras = np.diag([-1.0, -1.0, 1.0, 1.0])
    assert np.allclose(read_slicer_transform(path), np.linalg.inv(ras @ itk @ ras))


def test_bad_slicer_files(tmp_path):
    path = tmp_path / "bad.tfm"
    path.write_text("hello\n")
    with pytest.raises(InvalidInputError, match="not an ITK transform file"):
        read_slicer_transform(path)
    path.write_text("#Insight Transform File V1.0\nTransform: BSplineTransform_double_3_3\nParameters: 1\n")
    with pytest.raises(InvalidInputError, match="not a 3-D affine"):
        read_slicer_transform(path)


def plus_sequence(path, tracker_from_marker, base_from_tcp, times_s):
    """A PLUS sequence file of the marker's and the TCP's poses, one frame per row."""
    lines = ["ObjectType = Image", "NDims = 3", f"DimSize = 0 0 {len(times_s)}"]
    for k, (marker, tcp, time_s) in enumerate(zip(tracker_from_marker, base_from_tcp, times_s)):
        lines.append(
            f"Seq_Frame{k:04d}_MarkerToTrackerTransform = " + " ".join(repr(float(v)) for v in marker.ravel())
        )
        lines.append(f"Seq_Frame{k:04d}_MarkerToTrackerTransformStatus = OK")
        lines.append(
            f"Seq_Frame{k:04d}_TCPToBaseTransform = " + " ".join(repr(float(v)) for v in tcp.ravel())
        )
        lines.append(f"Seq_Frame{k:04d}_Timestamp = {float(time_s)!r}")
    lines.append("ElementDataFile = LOCAL")
    path.write_text("\n".join(lines) + "\n")
    return path


def test_plus_sequence_imports_as_a_recording(tmp_path, white_simulation):
    rec = white_simulation.recording
    rows = np.flatnonzero(rec.visible)[:20]
    sequence = plus_sequence(
        tmp_path / "robot.igs.mha",
        rec.tracker_from_marker_stack[rows],
        rec.base_from_tcp_stack[rows],
        rec.time_s[rows],
    )
    imported = recording_from_plus_sequence(sequence)
    assert len(imported) == 20 and np.all(np.isnan(imported.joints_rad))
    assert np.allclose(imported.tracker_from_marker_stack, rec.tracker_from_marker_stack[rows], atol=1e-9)
    again = read_recording(write_recording(imported, tmp_path / "imported.csv"))
    assert np.all(np.isnan(again.joints_rad)) and np.allclose(
        again.base_from_tcp_stack, imported.base_from_tcp_stack
    )


@pytest.mark.parametrize("scale", [1.5, 1.01, -1.0])
def test_a_plus_marker_that_is_not_rigid_is_refused_not_made_rigid(tmp_path, white_simulation, scale):
    """A scaled (1.5, 1 %) or mirrored marker pose in frame 7 is not a pose: one line naming the
    file, the transform and the frame. Single-precision poses (the control) still import."""
    rec = white_simulation.recording
    rows = np.flatnonzero(rec.visible)[:20]
    markers = rec.tracker_from_marker_stack[rows].astype(np.float32).astype(float)
    single = plus_sequence(
        tmp_path / "single.igs.mha", markers, rec.base_from_tcp_stack[rows], rec.time_s[rows]
    )
    assert len(recording_from_plus_sequence(single)) == 20
    markers[6, :3, :3] *= scale
    bad = plus_sequence(tmp_path / "scaled.igs.mha", markers, rec.base_from_tcp_stack[rows], rec.time_s[rows])
    with pytest.raises(
        InvalidInputError, match=r"scaled.igs.mha: MarkerToTracker: frame 7 is not a rigid transform"
    ):
        recording_from_plus_sequence(bad)
