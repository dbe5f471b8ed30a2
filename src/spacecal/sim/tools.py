"""The further tools and the phantom of the simulated world: a tracked pointer, a reference
marker rigidly on the needle guide, and a head phantom with fiducials and planned paths.

Each is built from a random stream of its own (never the streams that build the arm, the
layout and the tracker error, nor the marker's noise), so a scenario's calibration numbers do
not change because the world also holds these.

Frames (:mod:`spacecal.core.frames`): ``pointer`` is the pointer's marker frame and ``tip``
its pivot-calibrated tip; ``reference`` is the marker on the needle guide (its own tool
definition, not the calibrated marker); ``image_lps`` is the phantom's CT image space.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spacecal.core.errors import InvalidInputError, UnreachableError
from spacecal.geometry.transforms import apply_transform, invert_transform, make_transform, rotvec_to_matrix
from spacecal.models.marker import MarkerGeometry
from spacecal.models.tracker import TrackerModel

#: The stream numbers (``default_rng([seed, N])``) of the tools and the phantom: after the
#: world's 0 (truth), 1 (noise), 4 (controller), 5 (bias), 6 (marker geometry).
TOOLS_STREAM, PHANTOM_STREAM, TOOL_NOISE_STREAM, POINTER_HAND_STREAM = 7, 8, 9, 10

#: The name each further tool has in the world (and in a simulated tracker's frame).
POINTER, REFERENCE = "pointer", "reference"

#: RMS 3-D error (mm) of the pointer's pivot-calibrated tip: the experiments' phantom default.
POINTER_TIP_ERROR_MM = 0.2
#: Where the tip is in the pointer's frame (mm): 120 mm down the shaft from the first sphere.
POINTER_TIP_IN_POINTER = (0.0, 0.0, -120.0)
#: Where the guide's reference marker sits in the TCP frame (mm): beside the guide, apart from
#: the calibrated marker (which sits at the scenario's ``marker_offset_mm``).
REFERENCE_OFFSET_IN_TCP = (-40.0, 55.0, -110.0)
#: Largest tilt (deg) of a held pointer from facing the tracker squarely.
POINTER_TILT_DEG = 25.0
#: Draws of a pointer pose before a fiducial counts as not touchable in view.
POINTER_POSE_ATTEMPTS = 200


def pointer_geometry() -> MarkerGeometry:
    """A 4-sphere passive pointer, NDI 8700340-like: the spheres in the y-z plane, the face
    normal +x, the shaft along -z. Its sphere distances differ from the marker's (NDI 8700339)
    and the guide reference's, as a tracker needs to tell passive tools apart."""
    spheres = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 50.0], [0.0, 25.0, 100.0], [0.0, -25.0, 135.0]])
    return MarkerGeometry(name="NDI 8700340-like pointer", spheres_in_marker=spheres)


def reference_geometry() -> MarkerGeometry:
    """A 4-sphere passive reference for the needle guide, NDI 8700449-like (spheres in the
    y-z plane, face normal +x), its sphere distances unlike the marker's and the pointer's."""
    spheres = np.array([[0.0, 0.0, 0.0], [0.0, -30.0, 50.0], [0.0, 15.0, 85.0], [0.0, 40.0, 30.0]])
    return MarkerGeometry(name="NDI 8700449-like reference", spheres_in_marker=spheres)


@dataclass(frozen=True)
class PlannedPath:
    """A needle path planned in the phantom's CT image.

    Attributes
    ----------
    label : str
    entry_in_image, target_in_image : numpy.ndarray, shape (3,)
        In ``image_lps``, mm.
    """

    label: str
    entry_in_image: np.ndarray
    target_in_image: np.ndarray

    def to_dict(self) -> dict:
        return {
            "label": self.label,
            "entry_in_image_lps_mm": self.entry_in_image.tolist(),
            "target_in_image_lps_mm": self.target_in_image.tolist(),
        }


@dataclass(frozen=True)
class PhantomTruth:
    """A head phantom in the tracker's view, as it really is.

    Attributes
    ----------
    head_radii_mm : numpy.ndarray, shape (3,)
        Semi-axes of the ellipsoidal head about the image origin, along the image axes.
    fiducials_in_image : dict of str to numpy.ndarray, shape (3,)
        Fiducials on the head's surface by label (``F-1`` ...), in ``image_lps``, mm.
    tracker_from_image : numpy.ndarray, shape (4, 4)
        The true ``tracker_from_image_lps``, mm.
    paths : tuple of PlannedPath
        Needle paths planned in the image, reachable by the robot with the marker in view.
    """

    head_radii_mm: np.ndarray
    fiducials_in_image: dict[str, np.ndarray]
    tracker_from_image: np.ndarray
    paths: tuple[PlannedPath, ...]

    @property
    def labels(self) -> tuple[str, ...]:
        return tuple(self.fiducials_in_image)

    @property
    def fiducials_in_tracker(self) -> dict[str, np.ndarray]:
        """The fiducials' true positions (3,) in the tracker frame, mm, by label."""
        return {
            label: apply_transform(self.tracker_from_image, point)
            for label, point in self.fiducials_in_image.items()
        }

    def fiducial(self, which: int | str) -> tuple[str, np.ndarray]:
        """(label, position in the image (3,)) of fiducial ``which``: its label or its number
        counted from 1 (``F-1`` is 1).

        Raises
        ------
        InvalidInputError
            No such fiducial (one line listing them).
        """
        labels = self.labels
        label = labels[which - 1] if isinstance(which, int) and 1 <= which <= len(labels) else which
        if label not in self.fiducials_in_image:
            raise InvalidInputError(
                f"the phantom has no fiducial {which!r} "
                f"(its fiducials: 1..{len(labels)}, {', '.join(labels)})"
            )
        return str(label), self.fiducials_in_image[str(label)]

    def inside(self, points_in_image) -> np.ndarray:
        """Boolean (N,): the points (N, 3), mm, in ``image_lps`` are inside the head."""
        p = np.atleast_2d(np.asarray(points_in_image, float))
        return np.sum((p / self.head_radii_mm) ** 2, axis=1) < 1.0

    def to_dict(self) -> dict:
        """The truth as JSON-ready values (frames and units in the keys)."""
        in_tracker = self.fiducials_in_tracker
        return {
            "image_frame": "image_lps",
            "head_radii_mm": self.head_radii_mm.tolist(),
            "fiducials_in_image_lps_mm": {k: v.tolist() for k, v in self.fiducials_in_image.items()},
            "fiducials_in_tracker_mm": {k: v.tolist() for k, v in in_tracker.items()},
            "tracker_from_image_lps": self.tracker_from_image.tolist(),
            "paths": [path.to_dict() for path in self.paths],
        }


def surface_point(radii, direction) -> np.ndarray:
    """The point (3,) of the ellipsoid of semi-axes ``radii`` along ``direction`` (3,)."""
    direction = np.asarray(direction, dtype=float) / np.linalg.norm(direction)
    return direction / np.sqrt(np.sum((direction / np.asarray(radii, float)) ** 2))


def outward_normal(radii, point) -> np.ndarray:
    """The unit outward normal (3,) of the ellipsoid of semi-axes ``radii`` at ``point``."""
    normal = np.asarray(point, float) / np.asarray(radii, float) ** 2
    return normal / np.linalg.norm(normal)


def face_towards(normal_in_frame, up_in_frame, at_in_frame) -> np.ndarray:
    """``frame_from_marker`` (4, 4) of a marker at ``at`` whose face normal (+x) is ``normal``
    and whose long axis (+z) is ``up`` made perpendicular to it (all (3,), one frame)."""
    x = np.asarray(normal_in_frame, float) / np.linalg.norm(normal_in_frame)
    z = np.asarray(up_in_frame, float) - (np.asarray(up_in_frame, float) @ x) * x
    if np.linalg.norm(z) < 1e-9:
        z = np.cross(x, [1.0, 0.0, 0.0]) if abs(x[0]) < 0.9 else np.cross(x, [0.0, 1.0, 0.0])
    z /= np.linalg.norm(z)
    return make_transform(np.column_stack([x, np.cross(z, x), z]), at_in_frame)


def pointer_pose_at(
    fiducial_in_image,
    phantom_radii,
    tracker_from_image,
    pointer_from_tip,
    pointer: MarkerGeometry,
    tracker: TrackerModel,
    rng: np.random.Generator,
) -> np.ndarray:
    """A true ``tracker_from_pointer`` (4, 4) with the tip on a fiducial, held as a hand holds
    it: the pointer's face towards the tracker and its shaft out of the head, tilted at random
    up to :data:`POINTER_TILT_DEG`, every sphere in view and outside the head.

    Raises
    ------
    UnreachableError
        No such pose in :data:`POINTER_POSE_ATTEMPTS` draws (the fiducial faces away).
    """
    radii = np.asarray(phantom_radii, float)
    image_from_tracker = invert_transform(tracker_from_image)
    fiducial_in_tracker = apply_transform(tracker_from_image, fiducial_in_image)
    outward_in_tracker = tracker_from_image[:3, :3] @ outward_normal(radii, fiducial_in_image)
    to_camera = -fiducial_in_tracker / np.linalg.norm(fiducial_in_tracker)  # the camera at the origin
    tip_from_pointer = invert_transform(pointer_from_tip)
    for _ in range(POINTER_POSE_ATTEMPTS):
        tilt = rng.normal(size=3)
        tilt *= np.radians(POINTER_TILT_DEG) * rng.uniform() / np.linalg.norm(tilt)
        square = face_towards(to_camera, outward_in_tracker, [0.0, 0.0, 0.0])
        rotation = rotvec_to_matrix(tilt) @ square[:3, :3]
        tracker_from_tip = make_transform(rotation, fiducial_in_tracker)
        tracker_from_pointer = tracker_from_tip @ tip_from_pointer
        spheres_in_image = apply_transform(
            image_from_tracker @ tracker_from_pointer, pointer.spheres_in_marker
        )
        shaft = tracker_from_pointer[:3, :3] @ -np.asarray(pointer_from_tip)[:3, 3]
        if (
            bool(
                tracker.visible(
                    tracker_from_pointer[None], pointer.spheres_in_marker, pointer.face_normal_in_marker
                )[0]
            )
            and not np.any(np.sum((spheres_in_image / radii) ** 2, axis=1) < 1.0)
            and shaft @ outward_in_tracker > 0.3 * np.linalg.norm(shaft)
        ):
            return tracker_from_pointer
    raise UnreachableError("the pointer cannot touch this fiducial in the tracker's view")
