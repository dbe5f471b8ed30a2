"""A camera seeing a ChArUco board as a tracker: ``camera://`` (OpenCV's ``cv2.aruco``, extra
``camera``).

The source is an OpenCV capture (a device index, ``camera://0``) or a folder of images
(``camera:///abs/folder`` or ``camera:relative/folder``), read in sorted file-name order. Each
image's time is its row of a sidecar CSV (``times=FILE``, default ``times.csv`` in the folder
when there is one: columns ``file,time_s``) or its place in the order at a stated rate
(``rate=HZ``, default the run's tracker rate). A capture's frames are stamped with the
monotonic clock when they are grabbed.

The board is a JSON file (:func:`read_board`): squares along x and y, square and marker length
in mm, the ArUco dictionary's name, the legacy pattern flag (boards of OpenCV before 4.6.0 with
an even number of rows start with a marker, not a black square), and the id of its first marker.
The camera's intrinsics are a file (``intrinsics=FILE``, JSON or OpenCV YAML:
:func:`read_intrinsics`) or, for a folder, calibrated from the same images
(:func:`calibrate_intrinsics`: ``cv2.calibrateCamera`` on the ChArUco corners; its RMS
reprojection error is stated in the preflight and in :attr:`CameraTracker.intrinsics`).

Every frame the board is detected (``cv2.aruco.CharucoDetector``), its chessboard corners
interpolated from the markers, and ``camera_from_board`` estimated with ``cv2.solvePnP``
(iterative, refined by Levenberg-Marquardt) on those corners, in mm. A board not seen, or seen
with fewer than :data:`MIN_CORNERS` corners, is a frame without the marker (``missing``).

Mount (``mount=fixed|flange``), the two hand-eye forms:

* ``fixed`` (eye-to-hand): the camera stands beside the robot and the board is on the flange.
  The camera is the tracker and the board the marker: ``tracker_from_marker`` is
  ``camera_from_board``, and spacecal's model
  ``tracker_from_marker_i = tracker_from_base @ base_from_tcp_i @ tcp_from_marker`` holds as it
  is (``camera_from_base``, ``tcp_from_board``).
* ``flange`` (eye-in-hand): the camera is on the flange and the board fixed in the robot's
  world. Inverting the detection, ``board_from_camera_i = board_from_base @ base_from_tcp_i @
  tcp_from_camera``: the same model with the board as the fixed "tracker" and the camera as
  the "marker" on the tool. ``tracker_from_marker`` is ``board_from_camera``, and a calibration
  gives ``tracker_from_base`` = ``board_from_base`` and ``tcp_from_marker`` = ``tcp_from_camera``
  (the hand-eye transform). This is the duality :func:`spacecal.io.tum.raw_recording_from_tum`
  uses for an eye-in-hand trajectory.

Bad input is one line (:class:`~spacecal.core.errors.InvalidInputError`): a folder that cannot
be read or holds no image, an unreadable image, an intrinsics or board file that cannot be read
or is not one, a folder in which no image shows the board, and a board definition that
contradicts the image (markers whose ids are not the board's, or markers that do not measure
the stated marker length on the board's plane: a wrong marker or square length).
"""

from __future__ import annotations

import csv
import json
import math
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs

import numpy as np

from spacecal.adapters import DeviceAddress, DeviceOptions, require
from spacecal.core.errors import DeviceError, InvalidInputError
from spacecal.core.ports import (
    FINDING_OK,
    FINDING_PROBLEM,
    FINDING_WARNING,
    FRAME_MISSING,
    FRAME_OK,
    DeviceFinding,
    DeviceIdentity,
    TrackerFrame,
)
from spacecal.core.text import one_line_ascii
from spacecal.geometry.transforms import invert_transform, make_transform

#: The two mounts (the query's ``mount``): camera fixed (eye-to-hand), camera on the flange.
MOUNT_FIXED, MOUNT_FLANGE = "fixed", "flange"
MOUNTS = (MOUNT_FIXED, MOUNT_FLANGE)
#: Fewest interpolated chessboard corners a pose is estimated from: six points of a plane fix
#: its pose with some redundancy (four would fit any noise exactly).
MIN_CORNERS = 6
#: Fewest views with the board that intrinsics are calibrated from (``cv2.calibrateCamera``
#: needs three; a handful more keeps the focal length from trading against the distance).
MIN_CALIBRATION_VIEWS = 5
#: How far the markers' measured side may be from the board definition's: this fraction of it,
#: plus this many pixels at the board's distance. ArUco's marker corners (the polygon of the
#: marker's outline, not refined) sit about half a pixel inside the black border, and a blurred
#: image moves them further: a right board measures within 0.5 px of its side, a marker length
#: 10 % off is outside.
MARKER_SIZE_TOLERANCE, MARKER_CORNER_PX = 0.04, 1.5
#: Markers of the board seen without a corner between them that tell of a definition of another
#: layout: four markers of a ChArUco board share corners wherever the layout is the board's.
MIN_MARKERS_FOR_LAYOUT = 4
#: Image files read from a folder, by suffix.
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm")
#: The sidecar time file looked for in a folder when ``times`` is not given.
DEFAULT_TIMES_FILE = "times.csv"
#: How long opening a capture device may take, s.
OPEN_DEADLINE_S = 5.0
#: Query fields the ``camera://`` URL takes.
QUERY_FIELDS = ("board", "intrinsics", "mount", "rate", "times", "min_corners")


# -- the board -------------------------------------------------------------------------------
@dataclass(frozen=True)
class BoardDefinition:
    """A ChArUco board, as its JSON file states it.

    Attributes
    ----------
    squares_x, squares_y : int
        Chessboard squares along the board's x (columns) and y (rows), each at least 2.
    square_mm, marker_mm : float
        Side of a chessboard square and of an ArUco marker, mm (marker < square).
    dictionary : str
        An OpenCV predefined dictionary's name, e.g. ``DICT_5X5_100``.
    legacy : bool
        OpenCV's legacy pattern (boards made before 4.6.0 with an even number of rows).
    first_id : int
        The id of the board's first marker; its markers are ``first_id ..
        first_id + marker_count - 1``.

    Board frame: origin at the outer corner of the first (top-left) square, x along the
    columns, y along the rows, z into the board (OpenCV's ``CharucoBoard``), mm.
    """

    squares_x: int
    squares_y: int
    square_mm: float
    marker_mm: float
    dictionary: str
    legacy: bool = False
    first_id: int = 0
    path: str = field(default="", compare=False)

    def __post_init__(self) -> None:
        where = self.path or "board definition"
        for name in ("squares_x", "squares_y"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or not 2 <= value <= 100:
                raise InvalidInputError(
                    f"{where}: {name} must be a whole number of squares 2..100, got {value!r}"
                )
        for name in ("square_mm", "marker_mm"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or isinstance(value, bool) or not 0.1 <= value <= 2000.0:
                raise InvalidInputError(f"{where}: {name} must be a length 0.1..2000 mm, got {value!r}")
        if self.marker_mm >= self.square_mm:
            raise InvalidInputError(
                f"{where}: marker_mm ({self.marker_mm:g}) must be smaller than square_mm ({self.square_mm:g})"
            )
        if not isinstance(self.first_id, int) or isinstance(self.first_id, bool) or self.first_id < 0:
            raise InvalidInputError(f"{where}: first_id must be a whole number >= 0, got {self.first_id!r}")
        if not isinstance(self.legacy, bool):
            raise InvalidInputError(f"{where}: legacy must be true or false, got {self.legacy!r}")

    @property
    def marker_count(self) -> int:
        """Markers on the board: one in every white square, half of them."""
        return self.squares_x * self.squares_y // 2

    @property
    def marker_ids(self) -> range:
        return range(self.first_id, self.first_id + self.marker_count)

    @property
    def size_mm(self) -> tuple[float, float]:
        """The board's chessboard area, (x, y) mm."""
        return self.squares_x * self.square_mm, self.squares_y * self.square_mm

    def describe(self) -> str:
        return (
            f"{self.squares_x}x{self.squares_y} squares of {self.square_mm:g} mm, "
            f"markers {self.marker_mm:g} mm "
            f"{self.dictionary} ids {self.first_id}..{self.first_id + self.marker_count - 1}"
            + (", legacy pattern" if self.legacy else "")
        )

    def opencv_board(self) -> Any:
        """The ``cv2.aruco.CharucoBoard`` (mm).

        Raises
        ------
        InvalidInputError
            The dictionary is not one of OpenCV's, or has too few markers for the board.
        """
        cv2 = _cv2()
        code = getattr(cv2.aruco, self.dictionary, None) if self.dictionary.startswith("DICT_") else None
        if not isinstance(code, int):
            known = sorted(name for name in dir(cv2.aruco) if name.startswith("DICT_"))
            raise InvalidInputError(
                f"{self.path or 'board definition'}: dictionary {one_line_ascii(self.dictionary)!r} is not "
                f"one of OpenCV's ({', '.join(known[:6])}, ...)"
            )
        dictionary = cv2.aruco.getPredefinedDictionary(code)
        size = int(dictionary.bytesList.shape[0])
        if self.first_id + self.marker_count > size:
            raise InvalidInputError(
                f"{self.path or 'board definition'}: the board needs marker ids up to "
                f"{self.first_id + self.marker_count - 1}, and {self.dictionary} has {size} markers"
            )
        ids = np.arange(self.first_id, self.first_id + self.marker_count, dtype=np.int32)
        board = cv2.aruco.CharucoBoard(
            (self.squares_x, self.squares_y), float(self.square_mm), float(self.marker_mm), dictionary, ids
        )
        board.setLegacyPattern(bool(self.legacy))
        return board


def read_board(path: str | Path) -> BoardDefinition:
    """Read a board definition (JSON)::

        {"squares_x": 7, "squares_y": 5, "square_mm": 30, "marker_mm": 22,
         "dictionary": "DICT_5X5_100", "legacy": false, "first_id": 0}

    ``legacy`` and ``first_id`` are optional.

    Raises
    ------
    InvalidInputError
        The file cannot be read, is not JSON, lacks a field, or states a board that is not one.
    """
    path = Path(path)
    data = _read_json(path, "board definition")
    known = {"squares_x", "squares_y", "square_mm", "marker_mm", "dictionary", "legacy", "first_id"}
    missing = [
        key for key in ("squares_x", "squares_y", "square_mm", "marker_mm", "dictionary") if key not in data
    ]
    if missing:
        raise InvalidInputError(f"{path}: a board definition needs {', '.join(missing)}")
    unknown = sorted(set(data) - known)
    if unknown:
        raise InvalidInputError(f"{path}: unknown board field {one_line_ascii(unknown[0])!r}")
    if not isinstance(data["dictionary"], str):
        raise InvalidInputError(f"{path}: dictionary must be a name such as DICT_5X5_100")
    return BoardDefinition(
        data["squares_x"],
        data["squares_y"],
        data["square_mm"],
        data["marker_mm"],
        data["dictionary"],
        data.get("legacy", False),
        data.get("first_id", 0),
        path=str(path),
    )


def write_board(board: BoardDefinition, path: str | Path) -> Path:
    """Write a board definition as :func:`read_board` reads it."""
    fields = ("squares_x", "squares_y", "square_mm", "marker_mm", "dictionary", "legacy", "first_id")
    Path(path).write_text(json.dumps({name: getattr(board, name) for name in fields}, indent=2) + "\n")
    return Path(path)


# -- intrinsics -------------------------------------------------------------------------------
@dataclass(frozen=True)
class Intrinsics:
    """A pinhole camera with OpenCV's distortion model.

    Attributes
    ----------
    camera_matrix : numpy.ndarray, shape (3, 3)
        ``K``, px.
    distortion : numpy.ndarray, shape (D,)
        OpenCV's coefficients (k1, k2, p1, p2[, k3, ...]), D in 4, 5, 8, 12 or 14; zeros for none.
    image_size : tuple of int
        (width, height), px.
    rms_px : float or None
        RMS reprojection error of the calibration, px, when calibrated here (None: from a file).
    views : int
        Images the calibration used (0: from a file).
    source : str
        Where it came from, for messages.
    """

    camera_matrix: np.ndarray
    distortion: np.ndarray
    image_size: tuple[int, int]
    rms_px: float | None = None
    views: int = 0
    source: str = ""

    def __post_init__(self) -> None:
        where = self.source or "intrinsics"
        matrix = np.asarray(self.camera_matrix, dtype=float)
        distortion = np.asarray(self.distortion, dtype=float).ravel()
        if matrix.shape != (3, 3) or not np.all(np.isfinite(matrix)):
            raise InvalidInputError(f"{where}: the camera matrix must be 3x3 finite numbers")
        if not (
            matrix[0, 0] > 0 and matrix[1, 1] > 0 and np.allclose(matrix[2], [0, 0, 1]) and matrix[1, 0] == 0
        ):
            raise InvalidInputError(
                f"{where}: not a camera matrix (fx, fy > 0, last row 0 0 1): {np.round(matrix, 3).tolist()}"
            )
        if distortion.size not in (0, 4, 5, 8, 12, 14) or not np.all(np.isfinite(distortion)):
            raise InvalidInputError(
                f"{where}: {distortion.size} distortion coefficients (OpenCV takes 4, 5, 8, 12 or 14)"
            )
        width, height = (int(v) for v in self.image_size)
        if not (1 <= width <= 100_000 and 1 <= height <= 100_000):
            raise InvalidInputError(f"{where}: image size {self.image_size} is not one")
        object.__setattr__(self, "camera_matrix", matrix)
        object.__setattr__(self, "distortion", distortion if distortion.size else np.zeros(5))
        object.__setattr__(self, "image_size", (width, height))

    def describe(self) -> str:
        fx, fy = self.camera_matrix[0, 0], self.camera_matrix[1, 1]
        text = f"fx {fx:.1f} px, fy {fy:.1f} px, {self.image_size[0]}x{self.image_size[1]}"
        if self.rms_px is not None:
            return f"{text}, calibrated from {self.views} images: RMS reprojection {self.rms_px:.3f} px"
        return f"{text}, from {self.source}"


def read_intrinsics(path: str | Path) -> Intrinsics:
    """Read intrinsics from JSON or OpenCV YAML/XML (``cv2.FileStorage``).

    JSON: ``{"camera_matrix": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], "distortion": [k1, k2, p1,
    p2, k3], "image_size": [width, height]}`` (``K`` for ``camera_matrix``, ``dist_coeffs`` or ``D``
    for ``distortion`` also read). OpenCV YAML as ``calibrateCamera`` samples and ROS write it:
    ``camera_matrix`` (or ``K``), ``distortion_coefficients`` (or ``dist_coeffs``, ``D``), and
    ``image_width`` + ``image_height`` (or ``image_size``).

    Raises
    ------
    InvalidInputError
        The file cannot be read, or does not hold a camera matrix, distortion and image size.
    """
    path = Path(path)
    if path.suffix.lower() == ".json":
        data = _read_json(path, "intrinsics")
        matrix = _first(data, ("camera_matrix", "K"))
        distortion = _first(data, ("distortion", "dist_coeffs", "D"))
        size = data.get("image_size")
    else:
        matrix, distortion, size = _read_opencv_intrinsics(path)
    if matrix is None or distortion is None or size is None:
        raise InvalidInputError(
            f"{path}: intrinsics need a camera matrix, distortion coefficients and the image size"
        )
    try:
        matrix = np.asarray(matrix, dtype=float)
        if matrix.size == 9:
            matrix = matrix.reshape(3, 3)
        distortion = np.asarray(distortion, dtype=float).ravel()
        size = tuple(int(v) for v in np.asarray(size).ravel())
    except (TypeError, ValueError):
        raise InvalidInputError(f"{path}: the intrinsics are not numbers") from None
    if len(size) != 2:
        raise InvalidInputError(f"{path}: image size must be [width, height]")
    return Intrinsics(matrix, distortion, (size[0], size[1]), source=str(path))


def _first(data: dict, keys: Sequence[str]) -> Any:
    return next((data[key] for key in keys if key in data), None)


def _read_opencv_intrinsics(path: Path) -> tuple[Any, Any, Any]:
    cv2 = _cv2()
    if not path.is_file():
        raise InvalidInputError(f"{path}: no such intrinsics file")
    try:
        storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError):  # its parser's error surfaces as either
        raise InvalidInputError(f"{path}: not an OpenCV YAML/XML intrinsics file") from None
    try:
        if not storage.isOpened():
            raise InvalidInputError(f"{path}: not an OpenCV YAML/XML intrinsics file")

        def node(*names: str) -> Any:
            for name in names:
                item = storage.getNode(name)
                if item.empty():
                    continue
                if item.isSeq():
                    return [item.at(k).real() for k in range(item.size())]
                if item.isReal() or item.isInt():
                    return item.real()
                matrix = item.mat()  # an opencv-matrix
                if matrix is not None:
                    return matrix
            return None

        try:
            matrix = node("camera_matrix", "K", "cameraMatrix")
            distortion = node("distortion_coefficients", "dist_coeffs", "D", "distCoeffs")
            width, height = node("image_width"), node("image_height")
            size = node("image_size")
        except (cv2.error, SystemError):
            raise InvalidInputError(
                f"{path}: its intrinsics cannot be read (not OpenCV's matrices)"
            ) from None
        if size is None and width is not None and height is not None:
            size = [width, height]
        return matrix, distortion, size
    finally:
        storage.release()


# -- detection --------------------------------------------------------------------------------
@dataclass(frozen=True)
class Detection:
    """What one image shows of the board.

    Attributes
    ----------
    corner_ids : numpy.ndarray of int, shape (C,)
        Ids of the chessboard corners found (interpolated from the markers).
    corners_px : numpy.ndarray, shape (C, 2)
        Their image positions, px (pixel centres at integers).
    marker_ids : numpy.ndarray of int, shape (M,)
        The ArUco markers found (of the board's dictionary, the board's or not).
    marker_corners_px : numpy.ndarray, shape (M, 4, 2)
    """

    corner_ids: np.ndarray
    corners_px: np.ndarray
    marker_ids: np.ndarray
    marker_corners_px: np.ndarray


@dataclass(frozen=True)
class BoardPose:
    """The board's pose in one image.

    Attributes
    ----------
    camera_from_board : numpy.ndarray, shape (4, 4) or None
        mm; None when the board is not seen or has fewer than ``min_corners`` corners.
    corners : int
        Chessboard corners the pose was estimated from.
    reprojection_px : float
        RMS reprojection error of those corners, px (NaN without a pose).
    """

    camera_from_board: np.ndarray | None
    corners: int
    reprojection_px: float = float("nan")


class BoardDetector:
    """Detect one board and estimate its pose, checking what is seen against its definition."""

    def __init__(self, board: BoardDefinition, min_corners: int = MIN_CORNERS):
        cv2 = _cv2()
        self.definition = board
        self.board = board.opencv_board()
        self.min_corners = int(min_corners)
        self._detector = cv2.aruco.CharucoDetector(self.board)
        self._corner_points = np.asarray(self.board.getChessboardCorners(), dtype=float)
        self._marker_points = {
            int(i): np.asarray(p, dtype=float).reshape(4, 3)
            for i, p in zip(np.asarray(self.board.getIds()).ravel(), self.board.getObjPoints())
        }

    def detect(self, image: np.ndarray) -> Detection:
        """The board's corners and markers in a grey or colour image (uint8)."""
        cv2 = _cv2()
        grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        corners, corner_ids, marker_corners, marker_ids = self._detector.detectBoard(grey)
        if corner_ids is None or corners is None:
            corner_ids, corners = np.zeros(0, int), np.zeros((0, 2))
        if marker_ids is None:
            marker_ids, marker_corners = np.zeros(0, int), np.zeros((0, 4, 2))
        return Detection(
            np.asarray(corner_ids, dtype=int).ravel(),
            np.asarray(corners, dtype=float).reshape(-1, 2),
            np.asarray(marker_ids, dtype=int).ravel(),
            np.asarray(marker_corners, dtype=float).reshape(-1, 4, 2),
        )

    def corner_points(self, corner_ids: np.ndarray) -> np.ndarray:
        """The chessboard corners (C, 3) in the board frame, mm."""
        return self._corner_points[np.asarray(corner_ids, dtype=int)]

    def check_ids(self, detection: Detection, where: str) -> None:
        """Refuse markers of the board's dictionary whose ids are not on the board, when they
        are at least half of the markers seen (a stray marker of another board in the scene
        is passed over; a board seen through another's definition is not).

        Raises
        ------
        InvalidInputError
            The markers seen are not the board's: the definition describes another board.
        """
        foreign = sorted(set(detection.marker_ids.tolist()) - set(self.definition.marker_ids))
        if foreign and len(foreign) * 2 >= len(detection.marker_ids):
            ids = self.definition.marker_ids
            raise InvalidInputError(
                f"{where}: markers {_id_list(foreign)} of {self.definition.dictionary} are not on the board "
                f"(its ids {ids.start}..{ids.stop - 1}): the board definition "
                f"{self.definition.path or ''} describes another board".replace("  ", " ")
            )

    def pose(self, image: np.ndarray, intrinsics: Intrinsics, where: str) -> BoardPose:
        """``camera_from_board`` (mm) of the board in ``image``.

        Raises
        ------
        InvalidInputError
            The image's size is not the intrinsics', or the board seen contradicts its
            definition (:meth:`check_ids`, :meth:`check_markers`).
        """
        height, width = image.shape[:2]
        if (width, height) != intrinsics.image_size:
            raise InvalidInputError(
                f"{where}: the image is {width}x{height} px and the intrinsics are for "
                f"{intrinsics.image_size[0]}x{intrinsics.image_size[1]}"
            )
        detection = self.detect(image)
        self.check_ids(detection, where)
        if len(detection.corner_ids) < self.min_corners:
            return BoardPose(None, len(detection.corner_ids))
        camera_from_board, rms = self.solve(detection, intrinsics)
        if camera_from_board is None:
            return BoardPose(None, len(detection.corner_ids))
        self.check_markers(detection, camera_from_board, intrinsics, where)
        return BoardPose(camera_from_board, len(detection.corner_ids), rms)

    def solve(self, detection: Detection, intrinsics: Intrinsics) -> tuple[np.ndarray | None, float]:
        """solvePnP on the chessboard corners: (``camera_from_board`` mm or None, RMS px)."""
        cv2 = _cv2()
        points = self.corner_points(detection.corner_ids)
        pixels = detection.corners_px
        if _collinear(points):
            return None, float("nan")
        ok, rvec, tvec = cv2.solvePnP(
            points, pixels, intrinsics.camera_matrix, intrinsics.distortion, flags=cv2.SOLVEPNP_IPPE
        )
        if not ok:
            return None, float("nan")
        rvec, tvec = cv2.solvePnPRefineLM(
            points, pixels, intrinsics.camera_matrix, intrinsics.distortion, rvec, tvec
        )
        if not (np.all(np.isfinite(rvec)) and np.all(np.isfinite(tvec))) or float(tvec[2, 0]) <= 0:
            return None, float("nan")
        projected, _ = cv2.projectPoints(points, rvec, tvec, intrinsics.camera_matrix, intrinsics.distortion)
        rms = float(np.sqrt(np.mean(np.sum((projected.reshape(-1, 2) - pixels) ** 2, axis=1))))
        return make_transform(cv2.Rodrigues(rvec)[0], tvec.ravel()), rms

    def check_markers(
        self, detection: Detection, camera_from_board: np.ndarray, intrinsics: Intrinsics, where: str
    ) -> float:
        """The side of the board's markers (mm, the median over those seen) as the fitted pose
        measures them: their detected corners carried onto the board's plane. Refused when it
        is not the definition's ``marker_mm`` within :data:`MARKER_SIZE_TOLERANCE` of it plus
        :data:`MARKER_CORNER_PX` pixels at the board's distance.

        The chessboard corners fit a plane whatever the square length (a larger board farther
        away looks the same); the markers, sized by the marker length within the squares, do
        not measure their stated side when the ratio of the two lengths is wrong.

        Returns
        -------
        float
            The measured side, mm (NaN when none of the board's markers was seen).

        Raises
        ------
        InvalidInputError
            The markers are not the size the board definition gives them.
        """
        cv2 = _cv2()
        own = [k for k, i in enumerate(detection.marker_ids) if int(i) in self._marker_points]
        if not own:
            return float("nan")
        corners = detection.marker_corners_px[own].reshape(-1, 1, 2)
        normalised = cv2.undistortPoints(corners, intrinsics.camera_matrix, intrinsics.distortion).reshape(
            -1, 2
        )
        # the plane z = 0 of the board: camera ray (u, v, 1) ~ [r1 r2 t] (x, y, 1)
        plane = np.column_stack(
            [camera_from_board[:3, 0], camera_from_board[:3, 1], camera_from_board[:3, 3]]
        )
        on_board = np.linalg.solve(plane, np.column_stack([normalised, np.ones(len(normalised))]).T).T
        on_board = (on_board[:, :2] / on_board[:, 2:]).reshape(-1, 4, 2)
        sides = np.linalg.norm(on_board - np.roll(on_board, 1, axis=1), axis=2).mean(axis=1)
        side = float(np.median(sides))
        mm_per_px = float(camera_from_board[2, 3]) / float(intrinsics.camera_matrix[0, 0])
        allowed = MARKER_SIZE_TOLERANCE * self.definition.marker_mm + MARKER_CORNER_PX * mm_per_px
        if abs(side - self.definition.marker_mm) > allowed:
            raise InvalidInputError(
                f"{where}: the markers measure {side:.1f} mm on the board and the board definition says "
                f"{self.definition.marker_mm:g} mm ({self.definition.describe()}): check marker_mm and "
                "square_mm against the board"
            )
        return side


def _collinear(points: np.ndarray) -> bool:
    """True when the board points span no plane (all on one line): no pose from them."""
    centred = points - points.mean(axis=0)
    singular = np.linalg.svd(centred, compute_uv=False)
    return bool(singular[1] < 1e-6 * max(singular[0], 1e-12))


def _id_list(ids: Sequence[int]) -> str:
    shown = ", ".join(map(str, ids[:5]))
    return shown + (f" and {len(ids) - 5} more" if len(ids) > 5 else "")


def calibrate_intrinsics(detector: BoardDetector, images: Sequence[tuple[str, np.ndarray]]) -> Intrinsics:
    """Intrinsics from the board seen in ``images`` (``cv2.calibrateCamera`` on the ChArUco
    corners, five distortion coefficients).

    Parameters
    ----------
    images : sequence of (name, image)
        The images, all of one size; those with fewer than ``detector.min_corners`` corners
        are left out.

    Returns
    -------
    Intrinsics
        With ``rms_px`` the calibration's RMS reprojection error and ``views`` the images used.

    Raises
    ------
    InvalidInputError
        Fewer than :data:`MIN_CALIBRATION_VIEWS` images show the board, images of different
        sizes, or the calibration fails.
    """
    cv2 = _cv2()
    object_points, image_points, size = [], [], None
    for name, image in images:
        height, width = image.shape[:2]
        if size is None:
            size = (width, height)
        elif size != (width, height):
            raise InvalidInputError(
                f"{name}: {width}x{height} px, and the images before it {size[0]}x{size[1]}"
            )
        detection = detector.detect(image)
        detector.check_ids(detection, name)
        if len(detection.corner_ids) >= detector.min_corners:
            points = detector.corner_points(detection.corner_ids)
            if not _collinear(points):
                object_points.append(points.astype(np.float32))
                image_points.append(detection.corners_px.astype(np.float32))
    if size is None or len(object_points) < MIN_CALIBRATION_VIEWS:
        raise InvalidInputError(
            f"{len(object_points)} of {len(images)} images show the board with at least "
            f"{detector.min_corners} corners; calibrating the camera needs {MIN_CALIBRATION_VIEWS} "
            "(or give intrinsics=FILE)"
        )
    try:
        rms, matrix, distortion, _, _ = cv2.calibrateCamera(object_points, image_points, size, None, None)
    except cv2.error as exc:
        raise InvalidInputError(
            f"calibrating the camera from the images failed: {one_line_ascii(str(exc))}"
        ) from None
    if not math.isfinite(rms):
        raise InvalidInputError(
            "calibrating the camera from the images failed (no finite reprojection error)"
        )
    return Intrinsics(matrix, distortion, size, float(rms), len(object_points), "the images")


# -- sources ----------------------------------------------------------------------------------
class FolderSource:
    """A folder of images in sorted file-name order, each with a time stamp.

    Parameters
    ----------
    folder : path
    times : path or None
        A CSV with columns ``file,time_s`` (one row per image); None: ``times.csv`` in the
        folder when there is one, else the file order at ``rate_hz``.
    rate_hz : float
        Frames per second of the file order.
    """

    def __init__(self, folder: str | Path, times: str | Path | None, rate_hz: float):
        self.folder = Path(folder)
        if not self.folder.is_dir():
            raise InvalidInputError(f"{self.folder}: no such image folder")
        try:
            files = sorted(p for p in self.folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        except OSError as exc:
            raise InvalidInputError(
                f"{self.folder}: cannot read the folder ({exc.strerror or exc})"
            ) from None
        if not files:
            raise InvalidInputError(f"{self.folder}: no images ({', '.join(IMAGE_SUFFIXES)}) in the folder")
        self.files = files
        if times is None and (self.folder / DEFAULT_TIMES_FILE).is_file():
            times = self.folder / DEFAULT_TIMES_FILE
        if times is not None:
            self.times_s = _read_times(Path(times), files)
            self.timing = f"time stamps from {times}"
        else:
            if not (math.isfinite(rate_hz) and 0 < rate_hz <= 10_000):
                raise InvalidInputError(f"{self.folder}: a frame rate must be 0..10000 Hz, got {rate_hz}")
            self.times_s = np.arange(len(files)) / float(rate_hz)
            self.timing = f"file order at {rate_hz:g} Hz"
        self.next_index = 0

    def __len__(self) -> int:
        return len(self.files)

    def image(self, index: int) -> np.ndarray:
        """Image ``index`` (grey, uint8).

        Raises
        ------
        InvalidInputError
            The file cannot be read as an image.
        """
        cv2 = _cv2()
        path = self.files[index]
        image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if image is None:
            raise InvalidInputError(f"{path}: cannot be read as an image")
        return image

    def read(self) -> tuple[int, float, str, np.ndarray]:
        """(index, time s, name, image) of the next image.

        Raises
        ------
        DeviceError
            Every image was read.
        """
        if self.next_index >= len(self.files):
            raise DeviceError(f"{self.folder}: no more images (all {len(self.files)} were read)")
        index = self.next_index
        self.next_index += 1
        return index, float(self.times_s[index]), str(self.files[index]), self.image(index)

    def close(self) -> None:
        self.next_index = len(self.files)


def _read_times(path: Path, files: Sequence[Path]) -> np.ndarray:
    try:
        with path.open(newline="") as handle:
            rows = list(csv.DictReader(handle))
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise InvalidInputError(f"{path}: cannot read the time stamps ({exc})") from None
    stamps: dict[str, float] = {}
    for line, row in enumerate(rows, start=2):
        try:
            name, value = row["file"].strip(), float(row["time_s"])
        except (KeyError, TypeError, ValueError, AttributeError):
            raise InvalidInputError(f"{path}: line {line}: expected columns file,time_s") from None
        if not math.isfinite(value):
            raise InvalidInputError(f"{path}: line {line}: time_s is not a number")
        stamps[name] = value
    missing = [f.name for f in files if f.name not in stamps]
    if missing:
        raise InvalidInputError(
            f"{path}: no time stamp for {one_line_ascii(missing[0])} ({len(missing)} image(s))"
        )
    times = np.array([stamps[f.name] for f in files])
    if np.any(np.diff(times) <= 0):
        k = int(np.flatnonzero(np.diff(times) <= 0)[0]) + 1
        raise InvalidInputError(
            f"{path}: the time of {files[k].name} does not follow the one before (sorted by name)"
        )
    return times


class CaptureSource:
    """An OpenCV capture device read by a grabbing thread, so that each read has a deadline
    (``VideoCapture.read`` itself blocks for as long as the driver does).

    Parameters
    ----------
    index : int
        The device index.
    opener : callable, optional
        ``opener(index)`` returns an object with ``isOpened()``, ``read()`` and ``release()``
        (default ``cv2.VideoCapture``); for tests.
    """

    def __init__(
        self, index: int, opener: Callable[[int], Any] | None = None, deadline_s: float = OPEN_DEADLINE_S
    ):
        self.index = index
        self.name = f"camera {index}"
        self._condition = threading.Condition()
        self._latest: tuple[int, float, np.ndarray] | None = None
        self._count = 0
        self._failed: str | None = None
        self._stop = threading.Event()
        self._capture: Any = None
        opened = threading.Event()
        if opener is None:
            cv2 = _cv2()
            opener = cv2.VideoCapture

        def run() -> None:
            try:
                self._capture = opener(index)
                if not self._capture.isOpened():
                    self._failed = f"{self.name} cannot be opened (not connected, or in use)"
                    return
            except Exception as exc:  # the driver's own error, kept as one line
                self._failed = f"{self.name} cannot be opened ({one_line_ascii(str(exc))})"
                return
            finally:
                opened.set()
            self._grab()

        self._thread = threading.Thread(target=run, name=f"camera-{index}", daemon=True)
        self._thread.start()
        if not opened.wait(deadline_s):
            self._stop.set()
            raise DeviceError(f"{self.name} did not open within {deadline_s:g} s")
        if self._failed:
            self._release()
            raise DeviceError(self._failed)

    def _grab(self) -> None:
        try:
            while not self._stop.is_set():
                ok, image = self._capture.read()
                stamp = time.monotonic()
                if not ok or image is None:
                    self._failed = f"{self.name} stopped delivering frames"
                    break
                with self._condition:
                    self._count += 1
                    self._latest = (self._count, stamp, image)
                    self._condition.notify_all()
        finally:
            with self._condition:
                self._condition.notify_all()
            self._release()

    def _release(self) -> None:
        capture, self._capture = self._capture, None
        if capture is not None:
            try:
                capture.release()
            except Exception:  # a device already gone
                pass

    def read(self, timeout_s: float, after: int) -> tuple[int, float, str, np.ndarray]:
        """(frame number, time s, name, image) of the newest frame after ``after``.

        Raises
        ------
        DeviceError
            No new frame within ``timeout_s``, or the device stopped.
        """
        deadline = time.monotonic() + timeout_s
        with self._condition:
            while self._latest is None or self._latest[0] <= after:
                if self._failed:
                    raise DeviceError(self._failed)
                if self._stop.is_set():
                    raise DeviceError(f"{self.name} was closed: no more frames")
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise DeviceError(f"no frame from {self.name} for {timeout_s:.1f} s")
                self._condition.wait(remaining)
            number, stamp, image = self._latest
        return number, stamp, f"{self.name} frame {number}", image

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)


# -- the tracker ------------------------------------------------------------------------------
class CameraTracker:
    """A camera and a ChArUco board as a tracker (see the module's description for the frames).

    Parameters
    ----------
    source : FolderSource or CaptureSource
    detector : BoardDetector
    intrinsics : Intrinsics or None
        None: calibrated from a folder's images (a capture needs them given).
    mount : {"fixed", "flange"}
        ``fixed``: ``tracker_from_marker`` is ``camera_from_board``; ``flange``: it is
        ``board_from_camera``.
    url : str
        For messages.
    """

    def __init__(
        self,
        source: FolderSource | CaptureSource,
        detector: BoardDetector,
        intrinsics: Intrinsics | None,
        mount: str = MOUNT_FIXED,
        url: str = "camera",
    ):
        if mount not in MOUNTS:
            raise InvalidInputError(
                f"{url}: mount must be {' or '.join(MOUNTS)}, got {one_line_ascii(mount)!r}"
            )
        self.source, self.detector, self.mount, self.url = source, detector, mount, url
        self.seen = self.frames = 0
        self.last_pose: BoardPose | None = None
        self._last_number = 0
        if intrinsics is None:
            if not isinstance(source, FolderSource):
                raise InvalidInputError(f"{url}: a capture device needs intrinsics=FILE")
            intrinsics = calibrate_intrinsics(
                detector, [(str(source.files[k]), source.image(k)) for k in range(len(source))]
            )
        self.intrinsics = intrinsics
        if isinstance(source, FolderSource):
            self._check_folder_shows_the_board()

    def _check_folder_shows_the_board(self) -> None:
        """A folder in which no image shows the board is not a recording of it (one line);
        one whose images show the board's markers but no chessboard corners between them is
        seen through a definition of another layout (the legacy pattern, the square count)."""
        source = self.source
        assert isinstance(source, FolderSource)
        most_markers = 0
        for k in range(len(source)):
            detection = self.detector.detect(source.image(k))
            self.detector.check_ids(detection, str(source.files[k]))
            if len(detection.corner_ids) >= self.detector.min_corners:
                return
            own = set(detection.marker_ids.tolist()) & set(self.detector.definition.marker_ids)
            most_markers = max(most_markers, len(own))
        definition = self.detector.definition
        if most_markers >= MIN_MARKERS_FOR_LAYOUT:
            raise InvalidInputError(
                f"{source.folder}: its images show up to {most_markers} of the board's markers but no "
                f"chessboard corners between them: the board definition ({definition.describe()}) is not "
                "the board's layout (check legacy, for boards of OpenCV before 4.6.0 with an even number "
                "of rows, and squares_x, squares_y)"
            )
        raise InvalidInputError(
            f"{source.folder}: none of its {len(source)} images shows the board "
            f"({definition.describe()}) with at least {self.detector.min_corners} corners "
            "(check the dictionary too)"
        )

    def next_frame(self, timeout_s: float) -> TrackerFrame:
        """The next image's board pose: ``camera_from_board`` (``mount=fixed``) or
        ``board_from_camera`` (``mount=flange``), mm; ``missing`` when the board is not seen.
        A capture waits at most ``timeout_s`` for a frame newer than the last one returned; a
        folder's next image is a local file, read at once (``timeout_s`` is not needed).

        Raises
        ------
        DeviceError
            No new frame within ``timeout_s`` (a capture), or no more images (a folder).
        InvalidInputError
            The image contradicts the board definition.
        """
        if isinstance(self.source, FolderSource):
            number, stamp, name, image = self.source.read()
        else:
            number, stamp, name, image = self.source.read(timeout_s, self._last_number)
            self._last_number = number
        pose = self.detector.pose(image, self.intrinsics, name)
        self.last_pose = pose
        self.frames += 1
        if pose.camera_from_board is None:
            return TrackerFrame(stamp, number, FRAME_MISSING, None)
        self.seen += 1
        reported = (
            pose.camera_from_board if self.mount == MOUNT_FIXED else invert_transform(pose.camera_from_board)
        )
        # pose-only: a camera has no sphere fit, its RMS is in px (self.last_pose), not mm
        return TrackerFrame(stamp, number, FRAME_OK, reported)

    def identity(self) -> DeviceIdentity:
        cv2 = _cv2()
        model = (
            "image folder" if isinstance(self.source, FolderSource) else f"OpenCV capture {self.source.index}"
        )
        return DeviceIdentity(model=model, firmware=f"OpenCV {cv2.__version__}")

    def preflight(self) -> list[DeviceFinding]:
        """Read-only: the board, the intrinsics (and a calibration's RMS), and for a folder
        how many of its images show the board; for a capture whether the board is seen now."""
        findings = [
            DeviceFinding(FINDING_OK, "board", self.detector.definition.describe()),
            DeviceFinding(FINDING_OK, "intrinsics", self.intrinsics.describe()),
            DeviceFinding(
                FINDING_OK,
                "mount",
                "camera fixed, board on the flange: camera_from_board"
                if self.mount == MOUNT_FIXED
                else "camera on the flange, board fixed: board_from_camera",
            ),
        ]
        if isinstance(self.source, FolderSource):
            poses = [
                self.detector.pose(self.source.image(k), self.intrinsics, str(self.source.files[k]))
                for k in range(len(self.source))
            ]
            seen = [p for p in poses if p.camera_from_board is not None]
            unseen = [self.source.files[k].name for k, p in enumerate(poses) if p.camera_from_board is None]
            text = f"{len(seen)} of {len(poses)} images ({self.source.timing})"
            if seen:
                text += f"; median corner reprojection {np.median([p.reprojection_px for p in seen]):.3f} px"
            if unseen:
                text += f"; not seen in {one_line_ascii(unseen[0])}" + (
                    f" and {len(unseen) - 1} more" if len(unseen) > 1 else ""
                )
            findings.append(DeviceFinding(FINDING_WARNING if unseen else FINDING_OK, "board seen", text))
            findings.append(
                DeviceFinding(
                    FINDING_WARNING,
                    "source",
                    "recorded images, read as fast as asked and stamped by the folder's clock: pair them "
                    "with the robot's poses of the same views (docs/camera.md), not with a live robot",
                )
            )
            return findings
        try:
            frame = self.next_frame(2.0)
        except DeviceError as exc:
            findings.append(DeviceFinding(FINDING_PROBLEM, "frames", str(exc)))
            return findings
        if frame.status == FRAME_OK:
            findings.append(DeviceFinding(FINDING_OK, "board seen", "in the current frame"))
        else:
            findings.append(
                DeviceFinding(FINDING_WARNING, "board seen", "not in the current frame: bring it into view")
            )
        return findings

    def close(self) -> None:
        """Release the capture (a folder: nothing more is read)."""
        self.source.close()


def _cv2() -> Any:
    return require("cv2", "camera")


def _read_json(path: Path, what: str) -> dict:
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise InvalidInputError(f"{path}: no such {what} file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InvalidInputError(
            f"{path}: cannot read the {what} ({getattr(exc, 'strerror', None) or exc})"
        ) from None
    except json.JSONDecodeError as exc:
        raise InvalidInputError(f"{path}: the {what} is not JSON (line {exc.lineno}: {exc.msg})") from None
    if not isinstance(data, dict):
        raise InvalidInputError(f"{path}: the {what} must be a JSON object")
    return data


@dataclass(frozen=True)
class CameraOptions:
    """The ``camera://`` URL's query, checked."""

    board: str
    intrinsics: str | None
    mount: str
    rate_hz: float
    times: str | None
    min_corners: int


def camera_options(url: str, query: str, options: DeviceOptions) -> CameraOptions:
    """Read the query of a ``camera://`` URL (:data:`QUERY_FIELDS`).

    Raises
    ------
    InvalidInputError
        No board, an unknown or repeated field, or a value that is not one.
    """
    fields = parse_qs(query, keep_blank_values=True)
    unknown = sorted(set(fields) - set(QUERY_FIELDS))
    if unknown:
        raise InvalidInputError(
            f"{url}: unknown field {one_line_ascii(unknown[0])!r} (it takes {', '.join(QUERY_FIELDS)})"
        )
    repeated = [name for name, values in fields.items() if len(values) > 1]
    if repeated:
        raise InvalidInputError(f"{url}: {repeated[0]} is given twice")
    value = {name: values[0].strip() for name, values in fields.items()}
    if not value.get("board"):
        raise InvalidInputError(f"{url}: needs board=FILE (the ChArUco board definition)")
    mount = value.get("mount", MOUNT_FIXED)
    if mount not in MOUNTS:
        raise InvalidInputError(f"{url}: mount must be {' or '.join(MOUNTS)}, got {one_line_ascii(mount)!r}")
    try:
        rate = float(value.get("rate", options.tracker_rate_hz))
        min_corners = int(value.get("min_corners", MIN_CORNERS))
    except ValueError:
        raise InvalidInputError(
            f"{url}: rate must be a number of Hz and min_corners a whole number"
        ) from None
    if not (math.isfinite(rate) and 0 < rate <= 10_000):
        raise InvalidInputError(f"{url}: rate must be 0..10000 Hz, got {rate}")
    if min_corners < 4:
        raise InvalidInputError(f"{url}: min_corners must be at least 4 (a plane's pose), got {min_corners}")
    return CameraOptions(
        value["board"], value.get("intrinsics") or None, mount, rate, value.get("times") or None, min_corners
    )


def open_camera(
    source: str,
    board: str,
    intrinsics: str | None = None,
    mount: str = MOUNT_FIXED,
    rate_hz: float = 20.0,
    times: str | None = None,
    min_corners: int = MIN_CORNERS,
    url: str | None = None,
) -> CameraTracker:
    """Open a camera tracker: ``source`` a device index (digits) or an image folder."""
    url = url or f"camera:{source}"
    definition = read_board(board)
    detector = BoardDetector(definition, min_corners)
    given = read_intrinsics(intrinsics) if intrinsics else None
    if source.isdigit():
        opened: FolderSource | CaptureSource = CaptureSource(int(source))
    else:
        opened = FolderSource(source, times, rate_hz)
    try:
        return CameraTracker(opened, detector, given, mount, url)
    except BaseException:
        opened.close()
        raise


def open_device(address: DeviceAddress, options: DeviceOptions) -> CameraTracker:
    """The ``camera://`` row of the URL table (:data:`spacecal.adapters.DEVICE_SCHEMES`):
    ``camera://INDEX?board=FILE[&intrinsics=FILE][&mount=fixed|flange][&rate=HZ]
    [&times=FILE][&min_corners=N]`` or ``camera:///abs/folder?...`` / ``camera:folder?...``."""
    url = address.url
    if not address.serial and not address.host.isdigit():
        raise InvalidInputError(
            f"{url}: a camera is a device index (camera://0) or an image folder written "
            "camera:///absolute/folder or camera:relative/folder"
        )
    chosen = camera_options(url, address.query, options)
    return open_camera(
        address.host,
        chosen.board,
        chosen.intrinsics,
        chosen.mount,
        chosen.rate_hz,
        chosen.times,
        chosen.min_corners,
        url,
    )
