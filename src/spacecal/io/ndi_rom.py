"""NDI passive tool definition files (``.rom``): the marker geometry a tracker is given.

The likelihood models the spheres of the marker in use, so the geometry a recording states
must be the one the tracker was given (``--rom``), never an assumed one. NDI does not publish
the format; its layout is known from the files NDI Tool Tracker and NDI 6D Architect write and
from independent readers of them (all fields little-endian):

============  ======================================================
bytes         content
============  ======================================================
0-2           ``NDI`` (then a NUL)
4-5           checksum: the sum of bytes 6 to the end, modulo 2^16
28            the number of markers (spheres), at most 20
72-311        marker positions, mm: 20 x 3 float32 (unused ones zero)
312-551       marker face normals: 20 x 3 float32
============  ======================================================

Files are 752 bytes. :func:`read_rom_marker` checks the signature, the count and that the
positions are finite, in a tool's range and distinct; :func:`rom_bytes` writes such a file
(for the tests' fake trackers and for users who have only the geometry).
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from spacecal.core.errors import InvalidInputError
from spacecal.models.marker import MarkerGeometry

ROM_SIGNATURE = b"NDI"
ROM_LENGTH = 752
MARKER_COUNT_OFFSET = 28
POSITIONS_OFFSET = 72
NORMALS_OFFSET = 312
MAX_MARKERS = 20
#: A passive tool's spheres lie within this distance of its origin (mm).
MAX_TOOL_EXTENT_MM = 500.0
#: Two spheres closer than this (mm) are one: an 11.5 mm sphere cannot overlap another.
MIN_SPHERE_DISTANCE_MM = 5.0


def rom_checksum(data: bytes) -> int:
    """The checksum a tool definition carries in bytes 4-5."""
    return sum(data[6:]) % 65536


def read_rom_marker(path: str | Path) -> MarkerGeometry:
    """The marker geometry of an NDI passive tool definition file.

    Parameters
    ----------
    path : str or Path
        A ``.rom`` file.

    Returns
    -------
    MarkerGeometry
        Named after the file; spheres (K, 3) in the tool's frame, mm; the face normal the mean
        of the markers' normals (or +z when they are all zero).

    Raises
    ------
    InvalidInputError
        For a file that is not a tool definition, one with a wrong checksum, fewer than 3 or
        more than 20 markers, or positions that are not finite, beyond
        :data:`MAX_TOOL_EXTENT_MM` or closer than :data:`MIN_SPHERE_DISTANCE_MM`.
    """
    path = Path(path)
    try:
        with open(path, "rb") as handle:
            data = handle.read(ROM_LENGTH + 1)
    except OSError as exc:
        raise InvalidInputError(f"{path}: cannot read the tool definition ({exc.strerror})") from None
    if not data.startswith(ROM_SIGNATURE) or len(data) < NORMALS_OFFSET + 12 * MAX_MARKERS:
        raise InvalidInputError(f"{path}: not an NDI tool definition (.rom) file")
    stored = struct.unpack_from("<H", data, 4)[0]
    if stored != rom_checksum(data):
        raise InvalidInputError(f"{path}: the tool definition's checksum does not match (a damaged file?)")
    count = data[MARKER_COUNT_OFFSET]
    if not 3 <= count <= MAX_MARKERS:
        raise InvalidInputError(
            f"{path}: the tool definition has {count} markers (3..{MAX_MARKERS} expected)"
        )
    layout = f"<{3 * count}f"
    spheres = np.array(struct.unpack_from(layout, data, POSITIONS_OFFSET), dtype=float).reshape(-1, 3)
    normals = np.array(struct.unpack_from(layout, data, NORMALS_OFFSET), dtype=float).reshape(-1, 3)
    if not (np.all(np.isfinite(spheres)) and np.all(np.isfinite(normals))):
        raise InvalidInputError(f"{path}: the tool definition holds non-finite marker positions")
    if np.max(np.abs(spheres)) > MAX_TOOL_EXTENT_MM:
        raise InvalidInputError(
            f"{path}: a marker {np.max(np.abs(spheres)):.0f} mm from the tool's origin (at most "
            f"{MAX_TOOL_EXTENT_MM:g} mm)"
        )
    distances = np.linalg.norm(spheres[:, None] - spheres[None], axis=2)[np.triu_indices(count, 1)]
    if np.min(distances) < MIN_SPHERE_DISTANCE_MM:
        raise InvalidInputError(
            f"{path}: two markers of the tool definition are {np.min(distances):.1f} mm apart"
        )
    normal = normals.mean(axis=0)
    length = float(np.linalg.norm(normal))
    face = normal / length if length > 1e-6 else np.array([0.0, 0.0, 1.0])
    return MarkerGeometry(name=path.stem, spheres_in_marker=spheres, face_normal_in_marker=face)


def rom_bytes(spheres_in_marker_mm: np.ndarray, face_normal: np.ndarray | None = None) -> bytes:
    """A tool definition (752 bytes) with these sphere positions (K, 3), mm, 3 <= K <= 20."""
    spheres = np.asarray(spheres_in_marker_mm, dtype=float)
    if spheres.ndim != 2 or spheres.shape[1] != 3 or not 3 <= len(spheres) <= MAX_MARKERS:
        raise InvalidInputError(f"a tool definition holds 3..{MAX_MARKERS} positions (K, 3)")
    normal = np.array([0.0, 0.0, 1.0]) if face_normal is None else np.asarray(face_normal, dtype=float)
    data = bytearray(ROM_LENGTH)
    data[0:3] = ROM_SIGNATURE
    data[MARKER_COUNT_OFFSET] = len(spheres)
    struct.pack_into(f"<{spheres.size}f", data, POSITIONS_OFFSET, *spheres.ravel())
    normals = np.tile(normal, (len(spheres), 1))
    struct.pack_into(f"<{normals.size}f", data, NORMALS_OFFSET, *normals.ravel())
    struct.pack_into("<H", data, 4, rom_checksum(bytes(data)))
    return bytes(data)
