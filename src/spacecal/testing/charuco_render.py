"""Rendered ChArUco images of known poses, and a simulated UR arm carrying the board or the
camera: the yardstick of the ``camera://`` tracker (:mod:`spacecal.adapters.camera`).

Rendering. The board's texture is OpenCV's own (``CharucoBoard.generateImage``, with a white
margin), mapped onto the image plane through the plane-to-image homography
``K [r1 r2 t]`` of ``camera_from_board`` (a pinhole camera without distortion), rendered at
:data:`SUPERSAMPLE` times the resolution and box-filtered down (so edges are anti-aliased as a
sensor's pixels integrate light), then optionally blurred (Gaussian, px) and given Gaussian
pixel noise (grey levels), rounded to 8 bits. Pixel centres are at integer coordinates, as
OpenCV's detectors and ``solvePnP`` take them.

Arm. A UR10 (its nominal model, :func:`spacecal.models.kinematics.forward_kinematics`) moves
through joint vectors drawn about a start posture; only poses in which the whole board is in the
image, at most :data:`MAX_VIEW_ANGLE_DEG` off the camera's axis, are kept. Eye-to-hand
(``fixed``): the board is on the flange (``flange_from_board``) and the camera stands in the
robot's world (``base_from_camera``). Eye-in-hand (``flange``): the camera is on the flange
(``flange_from_camera``) and the board stands in the world (``base_from_board``).
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from spacecal.adapters.camera import MOUNT_FIXED, MOUNT_FLANGE, BoardDefinition, Intrinsics
from spacecal.geometry.transforms import axis_angle_transform, invert_transform, make_transform
from spacecal.models.kinematics import forward_kinematics
from spacecal.models.robot_kinds import robot_kind

#: Rendering is done at this many times the image's resolution and averaged down.
SUPERSAMPLE = 3
#: Texture resolution of the board, px per mm.
TEXTURE_PX_PER_MM = 8.0
#: Grey level around the board.
BACKGROUND = 150
#: Poses whose board normal is farther than this off the line of sight are not kept.
MAX_VIEW_ANGLE_DEG = 55.0
#: Margin (px) the board's outline keeps from the image's edge.
IMAGE_MARGIN_PX = 15.0


def default_board() -> BoardDefinition:
    """A 7 x 5 board of 30 mm squares and 22 mm markers (DICT_5X5_100): 210 x 150 mm."""
    return BoardDefinition(7, 5, 30.0, 22.0, "DICT_5X5_100")


def default_intrinsics() -> Intrinsics:
    """A 960 x 720 camera of 900 px focal length, principal point off-centre, no distortion."""
    matrix = np.array([[900.0, 0.0, 483.0], [0.0, 905.0, 356.0], [0.0, 0.0, 1.0]])
    return Intrinsics(matrix, np.zeros(5), (960, 720), source="the renderer")


def render(
    board: BoardDefinition,
    intrinsics: Intrinsics,
    camera_from_board: np.ndarray | None,
    noise_grey: float = 0.0,
    blur_px: float = 0.0,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """One grey image (uint8, height x width) of the board at ``camera_from_board`` (mm).

    Parameters
    ----------
    camera_from_board : numpy.ndarray, shape (4, 4), or None
        None: an image without the board (the background and its noise).
    noise_grey : float
        Standard deviation of the pixel noise, grey levels (of 255).
    blur_px : float
        Standard deviation of a Gaussian blur, px (0: none).
    """
    import cv2

    rng = rng or np.random.default_rng(0)
    width, height = intrinsics.image_size
    s = SUPERSAMPLE
    if camera_from_board is None:
        image = np.full((height, width), float(BACKGROUND))
    else:
        texture, board_from_texture = _texture(board)
        # high-resolution pixel j covers low-resolution coordinate (j + 0.5) / s - 0.5
        to_high = np.array([[s, 0.0, (s - 1) / 2], [0.0, s, (s - 1) / 2], [0.0, 0.0, 1.0]])
        pose = np.asarray(camera_from_board, dtype=float)
        plane = np.column_stack([pose[:3, 0], pose[:3, 1], pose[:3, 3]])
        homography = to_high @ intrinsics.camera_matrix @ plane @ board_from_texture
        high = cv2.warpPerspective(
            texture,
            homography,
            (width * s, height * s),
            flags=cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=BACKGROUND,
        )
        image = cv2.resize(high.astype(np.float32), (width, height), interpolation=cv2.INTER_AREA).astype(
            float
        )
    if blur_px > 0:
        image = cv2.GaussianBlur(image, (0, 0), blur_px)
    if noise_grey > 0:
        image = image + rng.normal(0.0, noise_grey, image.shape)
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)


_TEXTURES: dict[BoardDefinition, tuple[np.ndarray, np.ndarray]] = {}


def _texture(board: BoardDefinition) -> tuple[np.ndarray, np.ndarray]:
    """The board's image and ``board_from_texture`` (3 x 3: texture pixel to board mm)."""
    if board not in _TEXTURES:
        ppm = TEXTURE_PX_PER_MM
        margin = int(round(board.square_mm * ppm / 2))
        width_mm, height_mm = board.size_mm
        size = (int(round(width_mm * ppm)) + 2 * margin, int(round(height_mm * ppm)) + 2 * margin)
        image = board.opencv_board().generateImage(size, marginSize=margin)
        # pixel u's centre is board x = (u + 0.5 - margin) / ppm
        offset = (0.5 - margin) / ppm
        board_from_texture = np.array([[1 / ppm, 0.0, offset], [0.0, 1 / ppm, offset], [0.0, 0.0, 1.0]])
        _TEXTURES[board] = (image, board_from_texture)
    return _TEXTURES[board]


def board_outline_px(
    board: BoardDefinition, intrinsics: Intrinsics, camera_from_board: np.ndarray
) -> np.ndarray:
    """The board's four outer corners projected (4, 2), px; NaN behind the camera."""
    width_mm, height_mm = board.size_mm
    margin = board.square_mm / 2
    corners = np.array(
        [
            [-margin, -margin, 0.0],
            [width_mm + margin, -margin, 0.0],
            [width_mm + margin, height_mm + margin, 0.0],
            [-margin, height_mm + margin, 0.0],
        ]
    )
    in_camera = corners @ camera_from_board[:3, :3].T + camera_from_board[:3, 3]
    if np.any(in_camera[:, 2] <= 1.0):
        return np.full((4, 2), np.nan)
    projected = in_camera @ intrinsics.camera_matrix.T
    return projected[:, :2] / projected[:, 2:]


def in_view(board: BoardDefinition, intrinsics: Intrinsics, camera_from_board: np.ndarray) -> bool:
    """The whole board (with its margin) in the image and facing the camera within
    :data:`MAX_VIEW_ANGLE_DEG`."""
    outline = board_outline_px(board, intrinsics, camera_from_board)
    width, height = intrinsics.image_size
    if not np.all(np.isfinite(outline)):
        return False
    inside = np.all(outline >= IMAGE_MARGIN_PX) and np.all(
        outline <= [width - 1 - IMAGE_MARGIN_PX, height - 1 - IMAGE_MARGIN_PX]
    )
    centre = (
        camera_from_board[:3, :3] @ np.array([*np.divide(board.size_mm, 2), 0.0]) + camera_from_board[:3, 3]
    )
    # the board's z axis points away from the camera that sees its face
    cosine = float(camera_from_board[:3, 2] @ centre / np.linalg.norm(centre))
    return bool(inside and cosine >= np.cos(np.radians(MAX_VIEW_ANGLE_DEG)))


def _looking_at(position: np.ndarray, target: np.ndarray, up_hint: np.ndarray) -> np.ndarray:
    """``base_from_camera`` for a camera at ``position`` whose +z (OpenCV's optical axis)
    points at ``target``."""
    z_axis = (target - position) / np.linalg.norm(target - position)
    x_axis = np.cross(up_hint, z_axis)
    x_axis /= np.linalg.norm(x_axis)
    return make_transform(np.column_stack([x_axis, np.cross(z_axis, x_axis), z_axis]), position)


#: The UR10's start posture (rad): the flange 0.8 m out in front, pointing down and forward.
START_JOINTS_RAD = np.array([0.0, -1.75, 1.9, -1.9, -1.5708, 0.3])
#: Half-widths of the joint draws about the start posture (rad): the wrist turns most.
JOINT_SPREAD_RAD = np.array([0.12, 0.10, 0.12, 0.45, 0.45, 0.8])


@dataclass(frozen=True)
class HandEyeScene:
    """A simulated arm carrying a board (``fixed``) or a camera (``flange``), with its truth.

    Attributes
    ----------
    mount : {"fixed", "flange"}
    board : BoardDefinition
    intrinsics : Intrinsics
    joints_rad : numpy.ndarray, shape (N, 6)
    base_from_flange : numpy.ndarray, shape (N, 4, 4), mm
    flange_from_marker : numpy.ndarray, shape (4, 4)
        The hand-eye truth: ``flange_from_board`` (fixed) or ``flange_from_camera`` (flange).
    tracker_from_base : numpy.ndarray, shape (4, 4)
        The fixed frame's truth: ``camera_from_base`` (fixed) or ``board_from_base`` (flange).
    camera_from_board : numpy.ndarray, shape (N, 4, 4), mm
        What the camera sees in each pose.
    """

    mount: str
    board: BoardDefinition
    intrinsics: Intrinsics
    joints_rad: np.ndarray
    base_from_flange: np.ndarray
    flange_from_marker: np.ndarray
    tracker_from_base: np.ndarray
    camera_from_board: np.ndarray

    @property
    def tracker_from_marker(self) -> np.ndarray:
        """(N, 4, 4): what the camera tracker reports (``camera_from_board`` or its inverse)."""
        if self.mount == MOUNT_FIXED:
            return self.camera_from_board
        return np.array([invert_transform(pose) for pose in self.camera_from_board])


def simulate_scene(
    mount: str,
    count: int,
    seed: int = 0,
    board: BoardDefinition | None = None,
    intrinsics: Intrinsics | None = None,
    distance_mm: float = 650.0,
) -> HandEyeScene:
    """``count`` poses of a UR10 in which the camera sees the whole board.

    Raises
    ------
    RuntimeError
        Fewer than ``count`` poses in view after many draws (a scene that does not work).
    """
    board = board or default_board()
    intrinsics = intrinsics or default_intrinsics()
    rng = np.random.default_rng(seed)
    model = robot_kind("UR10").model()
    start = forward_kinematics(model, START_JOINTS_RAD, to_tcp=False)
    width_mm, height_mm = board.size_mm
    centre_in_board = np.array([width_mm / 2, height_mm / 2, 0.0])
    if mount == MOUNT_FIXED:
        # the board's face along the flange's z, its centre 40 mm out, turned 25 deg about z
        flange_from_board = axis_angle_transform([0.0, 0.0, 1.0], np.radians(25.0), [0.0, 0.0, 0.0]) @ (
            axis_angle_transform([1.0, 0.0, 0.0], np.pi, [-width_mm / 2 + 12.0, height_mm / 2 - 8.0, 40.0])
        )
        board_centre = (start @ flange_from_board)[:3, :3] @ centre_in_board + (start @ flange_from_board)[
            :3, 3
        ]
        face = start[:3, 2]
        position = board_centre + distance_mm * _unit(face + np.array([0.25, -0.2, 0.3]))
        base_from_camera = _looking_at(position, board_centre, np.array([0.0, 0.0, 1.0]))
        flange_from_marker, tracker_from_base = flange_from_board, invert_transform(base_from_camera)
    elif mount == MOUNT_FLANGE:
        # looking out along the flange's z, 60 mm out and off its axis, tilted 12 deg
        flange_from_camera = axis_angle_transform(
            _unit([1.0, 0.4, 0.0]), np.radians(12.0), [45.0, -30.0, 60.0]
        ) @ (axis_angle_transform([0.0, 0.0, 1.0], np.radians(-70.0), [0.0, 0.0, 0.0]))
        base_from_camera = start @ flange_from_camera
        # the board's centre on the optical axis, its face towards the camera, turned a little
        facing = axis_angle_transform(_unit([0.3, 1.0, 0.0]), np.radians(15.0), [0.0, 0.0, 0.0])
        base_from_board = base_from_camera @ facing
        base_from_board[:3, 3] = base_from_camera[:3, 3] + distance_mm * base_from_camera[:3, 2]
        base_from_board[:3, 3] -= base_from_board[:3, :3] @ centre_in_board
        flange_from_marker, tracker_from_base = flange_from_camera, invert_transform(base_from_board)
    else:
        raise ValueError(f"mount must be {MOUNT_FIXED} or {MOUNT_FLANGE}")
    joints, flanges, seen = [], [], []
    for _ in range(200 * count):
        q = START_JOINTS_RAD + rng.uniform(-1.0, 1.0, 6) * JOINT_SPREAD_RAD
        base_from_flange = forward_kinematics(model, q, to_tcp=False)
        if mount == MOUNT_FIXED:
            camera_from_board = tracker_from_base @ base_from_flange @ flange_from_marker
        else:
            camera_from_board = invert_transform(base_from_flange @ flange_from_marker) @ invert_transform(
                tracker_from_base
            )
        if in_view(board, intrinsics, camera_from_board):
            joints.append(q)
            flanges.append(base_from_flange)
            seen.append(camera_from_board)
            if len(joints) == count:
                break
    if len(joints) < count:
        raise RuntimeError(f"only {len(joints)} of {count} poses in view")
    return HandEyeScene(
        mount,
        board,
        intrinsics,
        np.array(joints),
        np.array(flanges),
        flange_from_marker,
        tracker_from_base,
        np.array(seen),
    )


def _unit(vector: Any) -> np.ndarray:
    vector = np.asarray(vector, dtype=float)
    return vector / np.linalg.norm(vector)


def write_images(
    scene: HandEyeScene,
    folder: str | Path,
    noise_grey: float = 0.0,
    blur_px: float = 0.0,
    seed: int = 1,
    rate_hz: float | None = None,
) -> list[Path]:
    """Render every pose of ``scene`` into ``folder`` (``view-000.png`` ...), with
    ``times.csv`` (``file,time_s``: 0.5 s apart) unless ``rate_hz`` (then no sidecar)."""
    import cv2

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    paths = []
    for k, pose in enumerate(scene.camera_from_board):
        path = folder / f"view-{k:03d}.png"
        cv2.imwrite(str(path), render(scene.board, scene.intrinsics, pose, noise_grey, blur_px, rng))
        paths.append(path)
    if rate_hz is None:
        with (folder / "times.csv").open("w", newline="") as handle:
            writer = csv.writer(handle)
            writer.writerow(["file", "time_s"])
            for k, path in enumerate(paths):
                writer.writerow([path.name, f"{0.5 * k:.3f}"])
    return paths
