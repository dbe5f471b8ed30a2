"""Hand-eye calibration from rendered ChArUco images: spacecal's against OpenCV's, on the same
detected poses (``benchmarks/camera_hand_eye.py`` prints the table; ``tests/adapters/
test_camera.py`` checks it).

The images of a :class:`~spacecal.testing.charuco_render.HandEyeScene` are read through the
``camera://`` tracker (its URL, as ``acquire`` opens it); each frame's pose and the arm's
``base_from_flange`` of that view make a recording (TCP = flange), written as spacecal writes
one and calibrated by ``spacecal calibrate``'s app function (pose-only tracker). OpenCV gets the
same detected poses: ``cv2.calibrateHandEye`` (every method) and
``cv2.calibrateRobotWorldHandEye`` (both methods), in the forms each mount needs:

* eye-in-hand (``flange``): ``calibrateHandEye(gripper2base = base_from_flange,
  target2cam = camera_from_board)`` gives ``flange_from_camera``; ``calibrateRobotWorldHandEye(
  world2cam = camera_from_board, base2gripper = flange_from_base)`` gives ``board_from_base``
  and ``camera_from_flange``.
* eye-to-hand (``fixed``): the same calls with the roles swapped (OpenCV's documented use):
  ``gripper2base = flange_from_base``, ``target2cam = camera_from_board`` gives
  ``base_from_camera``; the robot-world form with ``world2cam = board_from_camera`` gives
  ``camera_from_base`` and ``board_from_flange``.

Errors are against the scene's truth: the hand-eye transform ``flange_from_marker``
(``flange_from_board`` or ``flange_from_camera``) and, where a method gives it, the fixed
frame ``tracker_from_base`` (``camera_from_base`` or ``board_from_base``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spacecal.adapters import TRACKER, DeviceOptions, open_device
from spacecal.adapters.camera import MOUNT_FIXED, Intrinsics, write_board
from spacecal.core.errors import DeviceError
from spacecal.core.ports import FRAME_OK
from spacecal.estimators import ESTIMATORS
from spacecal.estimators.registry import Need
from spacecal.geometry.rotations import rotation_angle
from spacecal.geometry.transforms import invert_transform, make_transform, mean_transform
from spacecal.records import Recording
from spacecal.testing.charuco_render import HandEyeScene, write_images

#: OpenCV's hand-eye methods by the names its constants carry.
HAND_EYE_METHODS = ("TSAI", "PARK", "HORAUD", "ANDREFF", "DANIILIDIS")
ROBOT_WORLD_METHODS = ("SHAH", "LI")
#: spacecal's methods compared: every registered method that needs only varied rotations, i.e.
#: maximum likelihood and the closed forms (``paper`` needs its sweeps, ``kinematic`` the arm's
#: joints and model: neither is a hand-eye solver on free views).
SPACECAL_METHODS = tuple(
    name for name, spec in ESTIMATORS.items() if spec.needs <= frozenset({Need.VARIED_ROTATION})
)


def write_intrinsics(intrinsics: Intrinsics, path: str | Path) -> Path:
    """Intrinsics as JSON, as :func:`spacecal.adapters.camera.read_intrinsics` reads them."""
    import json

    data = {
        "camera_matrix": intrinsics.camera_matrix.tolist(),
        "distortion": intrinsics.distortion.tolist(),
        "image_size": list(intrinsics.image_size),
    }
    Path(path).write_text(json.dumps(data, indent=2) + "\n")
    return Path(path)


@dataclass(frozen=True)
class Observed:
    """The tracker's frames of a scene's images.

    Attributes
    ----------
    time_s : numpy.ndarray, shape (N,)
    tracker_from_marker : numpy.ndarray, shape (N, 4, 4)
        NaN rows where the board was not seen.
    visible : numpy.ndarray of bool, shape (N,)
    intrinsics : Intrinsics
        The tracker's (given or calibrated from the images).
    """

    time_s: np.ndarray
    tracker_from_marker: np.ndarray
    visible: np.ndarray
    intrinsics: Intrinsics


def camera_url(scene: HandEyeScene, folder: Path, intrinsics_file: Path | None) -> str:
    """The ``camera://`` URL of the scene's rendered folder."""
    board = write_board(scene.board, folder.parent / f"{folder.name}-board.json")
    query = f"board={board}&mount={scene.mount}"
    if intrinsics_file is not None:
        query += f"&intrinsics={intrinsics_file}"
    return f"camera://{folder.resolve()}?{query}"


def observe(
    scene: HandEyeScene,
    folder: str | Path,
    noise_grey: float,
    blur_px: float,
    given_intrinsics: bool = True,
    seed: int = 1,
) -> Observed:
    """Render the scene into ``folder`` and read it back through the ``camera://`` tracker."""
    folder = Path(folder)
    write_images(scene, folder, noise_grey, blur_px, seed)
    intrinsics_file = (
        write_intrinsics(scene.intrinsics, folder.parent / f"{folder.name}-intrinsics.json")
        if given_intrinsics
        else None
    )
    tracker = open_device(camera_url(scene, folder, intrinsics_file), TRACKER, DeviceOptions())
    times, poses = [], []
    try:
        while True:
            try:
                frame = tracker.next_frame(1.0)
            except DeviceError:  # no more images
                break
            times.append(frame.time_s)
            seen = frame.status == FRAME_OK and frame.tracker_from_marker is not None
            poses.append(frame.tracker_from_marker if seen else np.full((4, 4), np.nan))
        intrinsics = tracker.intrinsics
    finally:
        tracker.close()
    stack = np.array(poses)
    return Observed(np.array(times), stack, np.all(np.isfinite(stack[:, :3, 3]), axis=1), intrinsics)


def recording_of(scene: HandEyeScene, observed: Observed) -> Recording:
    """The recording of the scene's views: ``base_from_tcp`` the flange, ``tracker_from_marker``
    the camera tracker's pose."""
    return Recording(
        time_s=observed.time_s,
        segment=np.full(len(observed.time_s), "views"),
        joints_rad=scene.joints_rad,
        base_from_tcp_stack=scene.base_from_flange,
        tracker_from_marker_stack=observed.tracker_from_marker,
        marker_rms_mm=np.full(len(observed.time_s), np.nan),
        metadata={
            "robot": {"model": "UR10", "name": "simulated UR10 (nominal kinematics)"},
            "tracker": {"name": f"camera:// (mount={scene.mount}), pose-only", "pose_only": True},
            "units": {"length": "mm", "angle": "rad", "time": "s"},
        },
    )


@dataclass(frozen=True)
class Row:
    """One method's errors: the hand-eye transform's and (NaN where not estimated) the fixed
    frame's, rotation deg and translation mm."""

    library: str
    method: str
    hand_eye_deg: float
    hand_eye_mm: float
    fixed_deg: float = float("nan")
    fixed_mm: float = float("nan")
    #: spacecal's own 1-sd prediction of the hand-eye translation error (the root of the trace
    #: of its covariance block, mm), where the method states one.
    predicted_hand_eye_mm: float = float("nan")


def pose_error(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """(rotation angle deg, translation distance mm) of ``estimate`` against ``truth``."""
    difference = invert_transform(truth) @ estimate
    return float(np.degrees(rotation_angle(difference[:3, :3]))), float(
        np.linalg.norm(estimate[:3, 3] - truth[:3, 3])
    )


def spacecal_rows(
    scene: HandEyeScene, observed: Observed, folder: str | Path, methods=SPACECAL_METHODS
) -> list[Row]:
    """Write the recording and calibrate it with each method (``spacecal calibrate``'s app
    function, ``--tracker-kind pose``)."""
    from spacecal.app.calibration import CalibrateSettings, calibrate
    from spacecal.io.recordings import write_recording

    folder = Path(folder)
    path = write_recording(recording_of(scene, observed), folder / f"camera-{scene.mount}.csv")
    rows = []
    for method in methods:
        output = folder / f"camera-{scene.mount}-{method}.json"
        result = calibrate(
            CalibrateSettings(str(path), str(output), method=method, tracker_kind="pose", force=True)
        ).record
        predicted = float("nan")
        if result.covariance is not None:
            names = list(result.covariance["parameters"])
            block = [names.index(f"tcp_from_marker.v_{axis}_mm") for axis in "xyz"]
            matrix = np.asarray(result.covariance["matrix"], dtype=float)
            predicted = float(np.sqrt(np.trace(matrix[np.ix_(block, block)])))
        rows.append(
            Row(
                "spacecal",
                method,
                *pose_error(result.tcp_from_marker, scene.flange_from_marker),
                *pose_error(result.tracker_from_base, scene.tracker_from_base),
                predicted,
            )
        )
    return rows


def _split(stack: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray]]:
    return [pose[:3, :3] for pose in stack], [pose[:3, 3].reshape(3, 1) for pose in stack]


def opencv_rows(scene: HandEyeScene, observed: Observed) -> list[Row]:
    """``cv2.calibrateHandEye`` (every method) and ``cv2.calibrateRobotWorldHandEye`` (both) on
    the views in which the board was seen."""
    import cv2

    seen = observed.visible
    reported = observed.tracker_from_marker[seen]
    base_from_flange = scene.base_from_flange[seen]
    flange_from_base = np.array([invert_transform(pose) for pose in base_from_flange])
    if scene.mount == MOUNT_FIXED:
        camera_from_board = reported
        board_from_camera = np.array([invert_transform(pose) for pose in reported])
        gripper2base, world2cam, base2gripper = flange_from_base, board_from_camera, flange_from_base
    else:
        camera_from_board = np.array([invert_transform(pose) for pose in reported])
        gripper2base, world2cam, base2gripper = base_from_flange, camera_from_board, flange_from_base
    rows = []
    for name in HAND_EYE_METHODS:
        rotation, translation = cv2.calibrateHandEye(
            *_split(gripper2base), *_split(camera_from_board), method=getattr(cv2, f"CALIB_HAND_EYE_{name}")
        )
        found = make_transform(rotation, translation.ravel())
        # the transform a hand-eye solver does not give is the mean over the views of what
        # its answer and each view make of it
        if scene.mount == MOUNT_FIXED:
            base_from_camera = found  # OpenCV's cam2gripper with the roles swapped: cam2base
            hand_eye = mean_transform(flange_from_base @ base_from_camera @ camera_from_board)
            fixed = invert_transform(base_from_camera)
        else:
            hand_eye = found  # flange_from_camera
            fixed = invert_transform(mean_transform(base_from_flange @ hand_eye @ camera_from_board))
        rows.append(
            Row(
                "OpenCV calibrateHandEye",
                name,
                *pose_error(hand_eye, scene.flange_from_marker),
                *pose_error(fixed, scene.tracker_from_base),
            )
        )
    for name in ROBOT_WORLD_METHODS:
        r_base, t_base, r_gripper, t_gripper = cv2.calibrateRobotWorldHandEye(
            *_split(world2cam),
            *_split(base2gripper),
            method=getattr(cv2, f"CALIB_ROBOT_WORLD_HAND_EYE_{name}"),
        )
        # fixed: world = the camera and "cam" = the board (camera_from_base, board_from_flange);
        # flange: world = the board (board_from_base, camera_from_flange)
        fixed = make_transform(r_base, t_base.ravel())
        hand_eye = invert_transform(make_transform(r_gripper, t_gripper.ravel()))
        rows.append(
            Row(
                "OpenCV calibrateRobotWorldHandEye",
                name,
                *pose_error(hand_eye, scene.flange_from_marker),
                *pose_error(fixed, scene.tracker_from_base),
            )
        )
    return rows
