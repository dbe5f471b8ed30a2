"""The ``camera://`` tracker on rendered ChArUco images of known poses: poses within what the
corners' errors allow, both mounts' frames, intrinsics calibrated from the images, time stamps,
the capture's deadline, every kind of bad input as one line; and a hand-eye calibration from
the images within the class of OpenCV's best solver.

No sockets or processes: the images are files, the capture a fake opener in this process."""

import json
import threading
import time

import cv2
import numpy as np
import pytest

from spacecal.adapters import TRACKER, DeviceOptions, open_device
from spacecal.adapters.camera import (
    MARKER_CORNER_PX,
    MOUNT_FIXED,
    MOUNT_FLANGE,
    BoardDefinition,
    BoardDetector,
    CameraTracker,
    CaptureSource,
    Intrinsics,
    read_intrinsics,
    write_board,
)
from spacecal.core.errors import DeviceError, InvalidInputError
from spacecal.core.ports import (
    FINDING_WARNING,
    FRAME_MISSING,
    FRAME_OK,
    Closable,
    Identified,
    Preflight,
    Tracker,
)
from spacecal.geometry.transforms import invert_transform
from spacecal.testing.camera_hand_eye import observe, opencv_rows, spacecal_rows, write_intrinsics
from spacecal.testing.charuco_render import (
    default_board,
    default_intrinsics,
    render,
    simulate_scene,
    write_images,
)

#: Pixel noise (grey levels, 1 sd) and blur (px) of the rendered images.
NOISE_GREY, BLUR_PX = 4.0, 0.7
#: The pose error may be this many of its standard deviations propagated from the corners'
#: errors (one-in-a-million for a Gaussian component; the corners' errors are not quite
#: independent, seen up to 3.8 sd over 90 views).
SIGMAS = 5.0


def one_line(caught) -> str:
    text = str(caught.value)
    assert "\n" not in text and "Traceback" not in text
    return text


def url_of(folder, board_file, intrinsics_file=None, mount=MOUNT_FIXED, extra="") -> str:
    query = f"board={board_file}&mount={mount}" + (
        f"&intrinsics={intrinsics_file}" if intrinsics_file else ""
    )
    return f"camera://{folder}?{query}{extra}"


@pytest.fixture
def board_file(tmp_path):
    return write_board(default_board(), tmp_path / "board.json")


@pytest.fixture
def intrinsics_file(tmp_path):
    return write_intrinsics(default_intrinsics(), tmp_path / "intrinsics.json")


def corner_error_sd(detector, detection, pose, intrinsics) -> tuple[float, np.ndarray]:
    """The detected corners' RMS error against their true projections (px), and the
    projection's Jacobian (2C, 6) in (rotation vector, translation mm) at the true pose."""
    points = detector.corner_points(detection.corner_ids)
    rvec = cv2.Rodrigues(pose[:3, :3])[0]
    projected, jacobian = cv2.projectPoints(points, rvec, pose[:3, 3], intrinsics.camera_matrix, np.zeros(5))
    error = detection.corners_px - projected.reshape(-1, 2)
    return float(np.sqrt(np.mean(error**2))), jacobian[:, :6]


@pytest.mark.parametrize("mount", [MOUNT_FIXED, MOUNT_FLANGE])
@pytest.mark.parametrize("noise_grey", [0.0, NOISE_GREY, 12.0])
def test_the_board_pose_is_the_rendered_one_within_what_the_corners_errors_allow(mount, noise_grey):
    scene = simulate_scene(mount, 12, seed=7)
    detector, intrinsics = BoardDetector(scene.board), scene.intrinsics
    rng = np.random.default_rng(3)
    sds = []
    for truth in scene.camera_from_board:
        image = render(scene.board, intrinsics, truth, noise_grey, BLUR_PX, rng)
        found = detector.pose(image, intrinsics, "view")
        assert found.camera_from_board is not None and found.corners >= 20
        sd, jacobian = corner_error_sd(detector, detector.detect(image), truth, intrinsics)
        sds.append(sd)
        # first-order propagation of independent corner errors of that size to the pose
        pose_sd = sd * np.sqrt(np.diag(np.linalg.inv(jacobian.T @ jacobian)))
        # in the rotation vector's components, as the Jacobian has them
        rotation_error = (
            cv2.Rodrigues(found.camera_from_board[:3, :3])[0] - cv2.Rodrigues(truth[:3, :3])[0]
        ).ravel()
        translation_error = found.camera_from_board[:3, 3] - truth[:3, 3]
        assert np.all(np.abs(rotation_error) <= SIGMAS * pose_sd[:3]), (rotation_error, pose_sd[:3])
        assert np.all(np.abs(translation_error) <= SIGMAS * pose_sd[3:]), (translation_error, pose_sd[3:])
        # a bound that means something: under 1 % of the distance, even at 12 grey levels of noise
        assert np.all(SIGMAS * pose_sd[3:] < 0.01 * truth[2, 3])
        # the fit's residual is the corners' error less the six parameters it took up
        assert found.reprojection_px <= 1.5 * sd + 0.01
    # more pixel noise, larger corner errors: the tolerance follows the injected noise
    assert np.median(sds) < 0.15


def test_noisier_images_give_larger_corner_errors():
    scene = simulate_scene(MOUNT_FIXED, 6, seed=2)
    detector = BoardDetector(scene.board)
    medians = []
    for noise in (0.0, 12.0, 30.0):
        rng = np.random.default_rng(5)
        sds = [
            corner_error_sd(
                detector,
                detector.detect(render(scene.board, scene.intrinsics, p, noise, BLUR_PX, rng)),
                p,
                scene.intrinsics,
            )[0]
            for p in scene.camera_from_board
        ]
        medians.append(np.median(sds))
    assert medians[0] < medians[1] < medians[2]


@pytest.mark.parametrize("mount", [MOUNT_FIXED, MOUNT_FLANGE])
def test_the_tracker_reports_camera_from_board_or_board_from_camera_by_mount(
    tmp_path, board_file, intrinsics_file, mount
):
    scene = simulate_scene(mount, 4, seed=1)
    folder = tmp_path / "views"
    write_images(scene, folder, NOISE_GREY, BLUR_PX)
    tracker = open_device(url_of(folder, board_file, intrinsics_file, mount), TRACKER, DeviceOptions())
    try:
        assert isinstance(tracker, Tracker) and isinstance(tracker, Closable)
        assert isinstance(tracker, Preflight) and isinstance(tracker, Identified)
        for k, truth in enumerate(scene.camera_from_board):
            frame = tracker.next_frame(1.0)
            assert frame.status == FRAME_OK and frame.time_s == pytest.approx(0.5 * k)  # times.csv
            detected = tracker.last_pose.camera_from_board
            expected = detected if mount == MOUNT_FIXED else invert_transform(detected)
            assert np.allclose(frame.tracker_from_marker, expected, atol=1e-9)
            # and near the truth (its precision: the test above); inverted, a rotation error
            # moves the camera by the board's distance times it (0.1 deg: 1 mm at 0.6 m)
            truth = truth if mount == MOUNT_FIXED else invert_transform(truth)
            assert np.linalg.norm(frame.tracker_from_marker[:3, 3] - truth[:3, 3]) < 3.0
            assert np.allclose(frame.tracker_from_marker[:3, :3], truth[:3, :3], atol=3e-3)
        with pytest.raises(DeviceError, match="no more images"):
            tracker.next_frame(1.0)
        assert "OpenCV" in tracker.identity().firmware
    finally:
        tracker.close()


def test_an_image_without_the_board_is_a_frame_without_the_marker(tmp_path, board_file, intrinsics_file):
    scene = simulate_scene(MOUNT_FIXED, 3, seed=4)
    folder = tmp_path / "views"
    write_images(scene, folder, NOISE_GREY, BLUR_PX, rate_hz=10.0)
    cv2.imwrite(str(folder / "view-001.png"), render(scene.board, scene.intrinsics, None, NOISE_GREY))
    tracker = open_device(
        url_of(folder, board_file, intrinsics_file, extra="&rate=10"), TRACKER, DeviceOptions()
    )
    try:
        frames = [tracker.next_frame(1.0) for _ in range(3)]
        assert [f.status for f in frames] == [FRAME_OK, FRAME_MISSING, FRAME_OK]
        assert frames[1].tracker_from_marker is None
        assert [f.time_s for f in frames] == pytest.approx([0.0, 0.1, 0.2])  # the file order at 10 Hz
        seen = {f.subject: f for f in tracker.preflight()}["board seen"]
        assert seen.level == FINDING_WARNING and "2 of 3 images" in seen.text and "view-001.png" in seen.text
    finally:
        tracker.close()


def test_intrinsics_are_calibrated_from_the_images_with_their_rms_stated(tmp_path, board_file):
    scene = simulate_scene(MOUNT_FIXED, 14, seed=9)
    folder = tmp_path / "views"
    write_images(scene, folder, NOISE_GREY, BLUR_PX)
    tracker = open_device(url_of(folder, board_file), TRACKER, DeviceOptions())
    try:
        found, truth = tracker.intrinsics, scene.intrinsics
        assert found.views == 14 and 0.0 < found.rms_px < 0.2
        # focal lengths and principal point to a fraction of a percent of the image
        assert np.allclose(np.diag(found.camera_matrix)[:2], np.diag(truth.camera_matrix)[:2], rtol=0.01)
        assert np.allclose(found.camera_matrix[:2, 2], truth.camera_matrix[:2, 2], atol=6.0)
        text = {f.subject: f.text for f in tracker.preflight()}["intrinsics"]
        assert f"RMS reprojection {found.rms_px:.3f} px" in text and "14 images" in text
        frame = tracker.next_frame(1.0)
        assert np.linalg.norm(frame.tracker_from_marker[:3, 3] - scene.camera_from_board[0][:3, 3]) < 5.0
    finally:
        tracker.close()


def test_opencv_yaml_intrinsics_are_read(tmp_path):
    truth = default_intrinsics()
    path = tmp_path / "camera.yaml"
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    storage.write("image_width", 960)
    storage.write("image_height", 720)
    storage.write("camera_matrix", truth.camera_matrix)
    storage.write("distortion_coefficients", np.array([[0.1, -0.2, 0.001, 0.002, 0.05]]))
    storage.release()
    read = read_intrinsics(path)
    assert np.array_equal(read.camera_matrix, truth.camera_matrix) and read.image_size == (960, 720)
    assert read.distortion.tolist() == [0.1, -0.2, 0.001, 0.002, 0.05] and read.rms_px is None


# -- bad input, each one line ------------------------------------------------------------------
@pytest.fixture
def views(tmp_path):
    scene = simulate_scene(MOUNT_FIXED, 3, seed=6)
    folder = tmp_path / "views"
    write_images(scene, folder, NOISE_GREY, BLUR_PX)
    return scene, folder


def test_a_board_of_other_marker_ids_contradicts_the_definition(tmp_path, views, intrinsics_file):
    _, folder = views
    other = write_board(
        BoardDefinition(7, 5, 30.0, 22.0, "DICT_5X5_100", first_id=40), tmp_path / "other.json"
    )
    with pytest.raises(InvalidInputError) as caught:
        open_device(url_of(folder, other, intrinsics_file), TRACKER, DeviceOptions())
    assert "are not on the board (its ids 40..56)" in one_line(caught)


def test_a_wrong_marker_length_contradicts_what_is_seen(tmp_path, views, intrinsics_file):
    scene, folder = views
    wrong = write_board(BoardDefinition(7, 5, 30.0, 18.0, "DICT_5X5_100"), tmp_path / "wrong.json")
    with pytest.raises(InvalidInputError) as caught:
        tracker = open_device(url_of(folder, wrong, intrinsics_file), TRACKER, DeviceOptions())
        try:
            tracker.next_frame(1.0)
        finally:
            tracker.close()
    text = one_line(caught)
    assert "the board definition says 18 mm" in text and "check marker_mm" in text
    # the right board: well within the limit
    detector = BoardDetector(scene.board)
    image = render(scene.board, scene.intrinsics, scene.camera_from_board[0], NOISE_GREY, BLUR_PX)
    detection = detector.detect(image)
    pose = detector.pose(image, scene.intrinsics, "view")
    side = detector.check_markers(detection, pose.camera_from_board, scene.intrinsics, "view")
    # ArUco corners sit about half a pixel inside the border: the side is short by about a pixel
    assert abs(side - 22.0) < MARKER_CORNER_PX * pose.camera_from_board[2, 3] / 900.0


def test_a_legacy_board_read_as_a_new_one_is_one_line(tmp_path, intrinsics_file):
    printed = BoardDefinition(6, 6, 25.0, 18.0, "DICT_5X5_100", legacy=True)
    scene = simulate_scene(MOUNT_FIXED, 3, seed=6, board=printed)
    folder = tmp_path / "views"
    write_images(scene, folder, NOISE_GREY, BLUR_PX)
    right = write_board(printed, tmp_path / "legacy.json")
    tracker = open_device(url_of(folder, right, intrinsics_file), TRACKER, DeviceOptions())
    try:
        assert tracker.next_frame(1.0).status == FRAME_OK
    finally:
        tracker.close()
    wrong = write_board(BoardDefinition(6, 6, 25.0, 18.0, "DICT_5X5_100"), tmp_path / "new.json")
    with pytest.raises(InvalidInputError) as caught:
        open_device(url_of(folder, wrong, intrinsics_file), TRACKER, DeviceOptions())
    assert "no chessboard corners between them" in one_line(caught) and "check legacy" in str(caught.value)


def test_a_folder_without_the_board_is_one_line(tmp_path, board_file, intrinsics_file):
    folder = tmp_path / "empty-views"
    folder.mkdir()
    for k in range(3):
        cv2.imwrite(
            str(folder / f"view-{k}.png"), render(default_board(), default_intrinsics(), None, NOISE_GREY)
        )
    with pytest.raises(InvalidInputError) as caught:
        open_device(url_of(folder, board_file, intrinsics_file, extra="&rate=5"), TRACKER, DeviceOptions())
    assert "none of its 3 images shows the board" in one_line(caught)


@pytest.mark.parametrize(
    ("case", "message"),
    [
        ("no folder", "no such image folder"),
        ("no images", "no images"),
        ("no intrinsics file", "no such intrinsics file"),
        ("intrinsics not JSON", "intrinsics is not JSON"),
        ("intrinsics without K", "need a camera matrix"),
        ("intrinsics YAML garbage", "not an OpenCV YAML/XML intrinsics file"),
        ("intrinsics of another size", "the intrinsics are for 640x480"),
        ("no board", "needs board=FILE"),
        ("board not JSON", "board definition is not JSON"),
        ("board of an unknown dictionary", "is not one of OpenCV's"),
        ("marker larger than square", "must be smaller than square_mm"),
        ("bad mount", "mount must be fixed or flange"),
        ("unknown field", "unknown field 'bard'"),
        ("unreadable image", "cannot be read as an image"),
        ("times missing an image", "no time stamp for view-002.png"),
        ("host form", "camera:///absolute/folder"),
        ("too few views to calibrate", "calibrating the camera needs 5"),
    ],
)
def test_bad_input_is_one_line(tmp_path, views, board_file, intrinsics_file, case, message):
    _, folder = views
    board, intrinsics, extra, where = board_file, intrinsics_file, "", str(folder)
    if case == "no folder":
        where = str(tmp_path / "nowhere")
    elif case == "no images":
        where = str(tmp_path)
        for path in tmp_path.glob("*.png"):
            path.unlink()
    elif case == "no intrinsics file":
        intrinsics = tmp_path / "missing.json"
    elif case == "intrinsics not JSON":
        intrinsics.write_text("{fx: 900")
    elif case == "intrinsics without K":
        intrinsics.write_text(json.dumps({"distortion": [0, 0, 0, 0], "image_size": [960, 720]}))
    elif case == "intrinsics YAML garbage":
        intrinsics = tmp_path / "camera.yaml"
        intrinsics.write_bytes(b"\x00\xff not yaml: [")
    elif case == "intrinsics of another size":
        small = Intrinsics(default_intrinsics().camera_matrix, np.zeros(5), (640, 480))
        intrinsics = write_intrinsics(small, tmp_path / "small.json")
    elif case == "no board":
        board = ""
    elif case == "board not JSON":
        board.write_text("squares: 7")
    elif case == "board of an unknown dictionary":
        board.write_text(json.dumps({**json.loads(board.read_text()), "dictionary": "DICT_9X9_7"}))
    elif case == "marker larger than square":
        board.write_text(json.dumps({**json.loads(board.read_text()), "marker_mm": 31}))
    elif case == "unknown field":
        extra = "&bard=x"
    elif case == "unreadable image":
        (folder / "view-001.png").write_bytes(b"not a png")
    elif case == "times missing an image":
        (folder / "times.csv").write_text("file,time_s\nview-000.png,0\nview-001.png,0.5\n")
    elif case == "host form":
        where = "images"
    elif case == "too few views to calibrate":
        intrinsics = None
    url = url_of(where, board, intrinsics, mount="ceiling" if case == "bad mount" else MOUNT_FIXED)
    with pytest.raises(InvalidInputError) as caught:
        tracker = open_device(url + extra, TRACKER, DeviceOptions())
        try:
            while True:
                tracker.next_frame(1.0)
        except DeviceError:
            pass
        finally:
            tracker.close()
    assert message in one_line(caught)


def test_a_relative_folder_keeps_its_case(tmp_path, monkeypatch, views, board_file, intrinsics_file):
    _, folder = views
    renamed = folder.rename(tmp_path / "Views")
    monkeypatch.chdir(tmp_path)
    tracker = open_device(
        f"camera:Views?board={board_file}&intrinsics={intrinsics_file}", TRACKER, DeviceOptions()
    )
    try:
        assert tracker.next_frame(1.0).status == FRAME_OK and renamed.is_dir()
    finally:
        tracker.close()


# -- a capture device --------------------------------------------------------------------------
class FakeCapture:
    """``cv2.VideoCapture``'s three calls: frames from a list, then a stall (a camera that stops
    delivering without an error, which only a deadline ends)."""

    def __init__(self, images, stall: threading.Event):
        self.images, self.stall, self.released = list(images), stall, False

    def isOpened(self):
        return True

    def read(self):
        if not self.images:
            self.stall.wait(5.0)
            return False, None
        time.sleep(0.02)
        return True, self.images.pop(0)

    def release(self):
        self.released = True


def test_a_capture_is_read_with_a_deadline_and_released_on_close():
    scene = simulate_scene(MOUNT_FIXED, 2, seed=8)
    images = [render(scene.board, scene.intrinsics, p, NOISE_GREY, BLUR_PX) for p in scene.camera_from_board]
    stall = threading.Event()
    capture = FakeCapture(images, stall)
    source = CaptureSource(0, opener=lambda index: capture)
    tracker = CameraTracker(source, BoardDetector(scene.board), scene.intrinsics, MOUNT_FIXED, "camera://0")
    try:
        numbers = set()
        for _ in range(2):
            frame = tracker.next_frame(2.0)
            numbers.add(frame.frame_number)
            assert frame.status == FRAME_OK
        start = time.monotonic()
        with pytest.raises(DeviceError, match="no frame from camera 0 for 0.3 s"):
            tracker.next_frame(0.3)
        assert time.monotonic() - start < 0.3 + 2.0
    finally:
        tracker.close()
        stall.set()
    source._thread.join(3.0)
    assert capture.released and not source._thread.is_alive()


def test_a_capture_needs_intrinsics():
    class Opened(FakeCapture):
        pass

    stall = threading.Event()
    source = CaptureSource(1, opener=lambda index: Opened([], stall))
    try:
        with pytest.raises(InvalidInputError) as caught:
            CameraTracker(source, BoardDetector(default_board()), None, MOUNT_FIXED, "camera://1")
        assert "needs intrinsics=FILE" in one_line(caught)
    finally:
        stall.set()
        source.close()


def test_a_capture_that_cannot_be_opened_is_one_line():
    class Closed:
        def isOpened(self):
            return False

        def release(self):
            pass

    with pytest.raises(DeviceError) as caught:
        CaptureSource(3, opener=lambda index: Closed())
    assert "camera 3 cannot be opened" in one_line(caught)


# -- hand-eye calibration from the images --------------------------------------------------------
#: "The same class" as OpenCV's best: at most twice its error, plus what the views' own scatter
#: of errors makes of a difference between methods on 20 views (0.01 deg, 0.1 mm).
CLASS_FACTOR, DEG_SLACK, MM_SLACK = 2.0, 0.01, 0.1


@pytest.mark.parametrize("mount", [MOUNT_FLANGE, MOUNT_FIXED])
def test_spacecal_calibrates_the_camera_within_the_class_of_opencvs_best(tmp_path, mount):
    scene = simulate_scene(mount, 20, seed=11)
    observed = observe(scene, tmp_path / "views", NOISE_GREY, BLUR_PX)
    assert observed.visible.all()
    (ml,) = spacecal_rows(scene, observed, tmp_path, methods=("ml",))
    opencv = opencv_rows(scene, observed)
    assert len(opencv) == 7  # five calibrateHandEye methods, two calibrateRobotWorldHandEye
    best_deg = min(row.hand_eye_deg for row in opencv)
    best_mm = min(row.hand_eye_mm for row in opencv)
    assert ml.hand_eye_deg <= CLASS_FACTOR * best_deg + DEG_SLACK, (ml, best_deg)
    assert ml.hand_eye_mm <= CLASS_FACTOR * best_mm + MM_SLACK, (ml, best_mm)
    best_fixed_mm = min(row.fixed_mm for row in opencv)
    assert ml.fixed_mm <= CLASS_FACTOR * best_fixed_mm + MM_SLACK, (ml, best_fixed_mm)
    # and its error is what it predicts: within four times the root of its covariance's trace
    # (a 3-D Gaussian error's norm exceeds that one time in 10^5 and more)
    assert 0.0 < ml.predicted_hand_eye_mm and ml.hand_eye_mm <= 4.0 * ml.predicted_hand_eye_mm, ml


# -- on the command line ---------------------------------------------------------------------------
def test_doctor_checks_a_camera_folder_and_refuses_a_wrong_board_in_one_line(
    tmp_path, capsys, views, intrinsics_file
):
    from spacecal.cli import main

    _, folder = views
    board = write_board(default_board(), tmp_path / "board.json")
    code = main(["doctor", "--tracker", url_of(folder, board, intrinsics_file)])
    out, err = capsys.readouterr()
    assert code == 0, out + err
    assert "3 of 3 images" in out and "fx 900.0 px" in out and "camera_from_board" in out
    other = write_board(
        BoardDefinition(7, 5, 30.0, 22.0, "DICT_5X5_100", first_id=40), tmp_path / "other.json"
    )
    code = main(["doctor", "--tracker", url_of(folder, other, intrinsics_file)])
    out, err = capsys.readouterr()
    lines = [line for line in (out + err).splitlines() if line.strip()]
    assert code == 1 and "Traceback" not in out + err
    assert sum("are not on the board" in line for line in lines) == 1
    assert any(line.startswith("tracker: configuration: PROBLEM:") for line in lines), lines
