"""Passive marker geometry."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class MarkerGeometry:
    """Sphere centres of a passive marker in its own frame.

    Attributes
    ----------
    name : str
    spheres_in_marker : numpy.ndarray, shape (K, 3), mm
    face_normal_in_marker : numpy.ndarray, shape (3,)
        Unit normal of the side the spheres are seen from.
    """

    name: str
    spheres_in_marker: np.ndarray
    face_normal_in_marker: np.ndarray = field(default_factory=lambda: np.array([1.0, 0.0, 0.0]))

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "spheres_in_marker_mm": self.spheres_in_marker.tolist(),
            "face_normal_in_marker": self.face_normal_in_marker.tolist(),
        }


def ndi_8700339_like() -> MarkerGeometry:
    """A 4-sphere planar marker with the layout of NDI's 8700339 passive reference.

    The spheres lie in the marker's y–z plane, the face normal is +x, and the origin is
    the first sphere, as in NDI's tool definition files.
    """
    spheres = np.array(
        [
            [0.0, 0.0, 0.0],
            [0.0, 28.59, 41.02],
            [0.0, 0.0, 88.0],
            [0.0, -44.32, 40.45],
        ]
    )
    return MarkerGeometry(name="NDI 8700339-like", spheres_in_marker=spheres)
