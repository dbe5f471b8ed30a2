"""The marker_status column: written, read back, checked, and old files without it."""

import numpy as np
import pytest

from spacecal.core.errors import InvalidInputError
from spacecal.core.ports import FRAME_MISSING, FRAME_OK, FRAME_OUT_OF_VOLUME, FRAME_PARTIALLY_OUT_OF_VOLUME
from spacecal.io.recording_csv import STATUS_COLUMN, RecordingWriter, read_recording, write_recording
from spacecal.records import Recording


def doubtful_copy(recording, rows, status=FRAME_PARTIALLY_OUT_OF_VOLUME):
    statuses = recording.marker_status.copy()
    statuses[rows] = status
    return Recording(**{**recording.__dict__, "marker_status": statuses})


def test_statuses_round_trip_and_doubtful_poses_are_kept(tmp_path, white_simulation):
    original = white_simulation.recording
    rows = np.flatnonzero(original.visible)[:5]
    recording = doubtful_copy(original, rows)
    again = read_recording(write_recording(recording, tmp_path / "rec.csv"))
    assert list(again.marker_status) == list(recording.marker_status)
    assert np.allclose(again.tracker_from_marker_stack[rows], original.tracker_from_marker_stack[rows])
    assert not again.visible[rows].any() and again.doubtful[rows].all()
    assert again.visible.sum() == original.visible.sum() - 5
    trusted = again.trusting_doubtful_frames()
    assert trusted.visible.sum() == original.visible.sum()
    assert trusted.metadata["doubtful_frames_included"] == 5


def test_old_files_without_the_column_read_as_ok_or_missing(tmp_path, recording_file, white_simulation):
    lines = recording_file.read_text().splitlines()
    header = lines[0].split(",")
    column = header.index(STATUS_COLUMN)
    old = [",".join(c for i, c in enumerate(line.split(",")) if i != column) for line in lines]
    path = tmp_path / "old.csv"
    path.write_text("\n".join(old) + "\n")
    recording = read_recording(path)
    seen = white_simulation.recording.visible
    assert set(recording.marker_status[seen]) == {FRAME_OK}
    assert set(recording.marker_status[~seen]) <= {FRAME_MISSING}
    assert np.array_equal(recording.visible, seen)


def test_resuming_an_old_file_keeps_its_layout(tmp_path, recording_file, white_simulation):
    lines = recording_file.read_text().splitlines()
    column = lines[0].split(",").index(STATUS_COLUMN)
    path = tmp_path / "old.csv"
    path.write_text(
        "\n".join(",".join(c for i, c in enumerate(l.split(",")) if i != column) for l in lines) + "\n"
    )
    rec = white_simulation.recording
    with RecordingWriter(path, append=True) as writer:
        writer.append(
            rec.time_s[-1] + 1.0,
            "extra",
            rec.joints_rad[-1],
            rec.base_from_tcp_stack[-1],
            status=FRAME_MISSING,
        )
    assert len(read_recording(path)) == len(rec) + 1


@pytest.mark.parametrize(
    ("status", "with_pose", "message"),
    [
        ("sort_of", True, "is not one of"),
        (FRAME_OK, False, "ok but the marker cells are empty"),
        (FRAME_MISSING, True, "missing but the marker cells hold a pose"),
    ],
)
def test_inconsistent_status_cells_are_refused(tmp_path, recording_file, status, with_pose, message):
    lines = recording_file.read_text().splitlines()
    header = lines[0].split(",")
    column, marker = header.index(STATUS_COLUMN), header.index("marker_x_mm")
    rows = [line.split(",") for line in lines[1:]]
    k = next(i for i, r in enumerate(rows) if bool(r[marker]) == with_pose)
    rows[k][column] = status
    path = tmp_path / "bad.csv"
    path.write_text("\n".join([lines[0]] + [",".join(r) for r in rows]) + "\n")
    with pytest.raises(InvalidInputError, match=message):
        read_recording(path)


def test_the_record_checks_its_statuses(white_simulation):
    recording = white_simulation.recording
    with pytest.raises(InvalidInputError, match="unknown marker status"):
        doubtful_copy(recording, [0], "fine")
    hidden = np.flatnonzero(~recording.visible)
    if len(hidden):
        with pytest.raises(InvalidInputError, match="'missing' but a marker pose"):
            Recording(
                **{
                    **recording.__dict__,
                    "marker_status": np.where(recording.visible, FRAME_MISSING, FRAME_OUT_OF_VOLUME),
                }
            )


def test_writer_keeps_a_doubtful_pose_and_drops_a_missing_one(tmp_path, white_simulation):
    rec = white_simulation.recording
    k = int(np.flatnonzero(rec.visible)[0])
    path = tmp_path / "w.csv"
    with RecordingWriter(path) as writer:
        for j in range(12):
            status = [FRAME_OUT_OF_VOLUME, FRAME_MISSING][j % 2] if j < 4 else None
            writer.append(
                rec.time_s[j],
                "s",
                rec.joints_rad[j],
                rec.base_from_tcp_stack[j],
                rec.tracker_from_marker_stack[k],
                0.1,
                status=status,
            )
    again = read_recording(path)
    assert list(again.marker_status[:4]) == [FRAME_OUT_OF_VOLUME, FRAME_MISSING] * 2
    assert again.has_pose[0] and not again.has_pose[1] and again.visible[4:].all()
