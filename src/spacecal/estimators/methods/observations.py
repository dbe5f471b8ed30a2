"""What the likelihood-based estimators observe: sphere positions in the tracker frame.

A marker pose measured by the tracker is a rigid fit of its spheres; to first order the
fitted pose carries the same information about the unknowns as the spheres themselves
(it is the rigid-fit projection of them). So every frame becomes K points: the raw sphere
centres when the recording has them (optional ``sphere{k}_x_mm`` columns), otherwise the
marker's model spheres placed by the measured pose. Residuals are then plain 3-D point
differences with an isotropic per-axis noise sigma, which the tracker's own RMS fit error
estimates.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.special import chdtri

from spacecal.core.errors import DegenerateDataError
from spacecal.geometry.arrays import ArrayLike, FloatArray
from spacecal.geometry.transforms import transform_points_by_stack
from spacecal.models.marker import ndi_8700339_like
from spacecal.records import Recording


@dataclass
class Observations:
    """Sphere observations of the visible frames of a recording.

    Attributes
    ----------
    rows : numpy.ndarray of int, shape (N,)
        Indices of the used frames in the recording.
    base_from_tcp_stack : numpy.ndarray, shape (N, 4, 4)
    spheres_in_marker : numpy.ndarray, shape (K, 3), mm
    spheres_in_tracker : numpy.ndarray, shape (N, K, 3), mm
    dof_per_frame : int
        Independent residual components per frame: 6 for fitted poses, 3K for raw spheres.
    sigma_mm : float
        Per-axis sphere noise, mm.
    sigma_known : bool
        False when the recording carries no tracker RMS and none was given: sigma is then a
        placeholder, covariances follow from the residuals alone.
    """

    rows: np.ndarray
    base_from_tcp_stack: np.ndarray
    spheres_in_marker: np.ndarray
    spheres_in_tracker: np.ndarray
    dof_per_frame: int
    sigma_mm: float
    sigma_known: bool = True

    def of_frames(self, frames: np.ndarray) -> Observations:
        """The observations of some of these frames (a mask of shape (N,) or indices into
        them), with the same marker and noise: a held-out block, or the rest."""
        return replace(
            self,
            rows=self.rows[frames],
            base_from_tcp_stack=self.base_from_tcp_stack[frames],
            spheres_in_tracker=self.spheres_in_tracker[frames],
        )


def sphere_noise_from_marker_rms(marker_rms_mm: ArrayLike, sphere_count: int) -> float:
    """Per-axis sphere noise sigma from the tracker's RMS fit errors.

    For K spheres with iid per-axis noise sigma, a rigid fit leaves 3K - 6 degrees of
    freedom: K rms^2 / sigma^2 follows chi-square(3K - 6). We use the median, so frames
    with a mis-detected sphere (large RMS) do not inflate the estimate:
    sigma^2 = K median(rms^2) / median(chi-square(3K - 6)).
    """
    rms = np.asarray(marker_rms_mm, dtype=float)
    rms = rms[np.isfinite(rms)]
    if len(rms) == 0 or np.all(rms == 0):
        return 0.0
    return float(np.sqrt(sphere_count * np.median(rms**2) / chdtri(3 * sphere_count - 6, 0.5)))


def marker_geometry_of(recording: Recording) -> FloatArray:
    """Sphere centres (K, 3) in the marker frame from the metadata (the tool definition in use),
    else an 8700339-like layout.

    The stand-in is used for trackers that send poses only (no geometry is known): placed by
    each measured pose it weights position against rotation as a tracked marker of that size
    would, and the noise model learns the actual weights from the residuals
    (:mod:`spacecal.estimators.methods.noise_model`).
    """
    marker = recording.metadata.get("marker", {})
    if "spheres_in_marker_mm" in marker:
        return np.asarray(marker["spheres_in_marker_mm"], dtype=float)
    return ndi_8700339_like().spheres_in_marker


def build_observations(
    recording: Recording,
    mask: ArrayLike | None = None,
    sigma_mm: float | None = None,
    minimum_sigma_mm: float = 1e-3,
) -> Observations:
    """Sphere observations of the visible (and masked-in) frames.

    Parameters
    ----------
    recording : Recording
    mask : array_like of bool, shape (N,), optional
        The frames to consider, N being the recording's frame count (all when omitted).
    sigma_mm : float, optional
        Per-axis sphere noise; estimated from ``marker_rms_mm`` if omitted (floored at
        ``minimum_sigma_mm`` so noise-free data stays well-posed).
    """
    use = recording.visible.copy()
    if mask is not None:
        use &= np.asarray(mask, dtype=bool)
    rows = np.flatnonzero(use)
    if len(rows) < 3:
        raise DegenerateDataError(f"only {len(rows)} frames with the marker visible; at least 3 are needed")
    spheres = marker_geometry_of(recording)
    raw = getattr(recording, "spheres_in_tracker", None)
    if raw is not None and np.all(np.isfinite(raw[rows])):
        observed, dof = raw[rows], 3 * len(spheres)
    else:
        poses = recording.tracker_from_marker_stack[rows]
        observed = transform_points_by_stack(poses, spheres)
        dof = 6
    known = True
    if sigma_mm is None:
        rms = recording.marker_rms_mm[rows]
        if np.isfinite(rms).sum() < 3:
            sigma_mm, known = 1.0, False
        else:
            sigma_mm = sphere_noise_from_marker_rms(rms, len(spheres))
    return Observations(
        rows,
        recording.base_from_tcp_stack[rows],
        spheres,
        observed,
        dof,
        max(float(sigma_mm), minimum_sigma_mm),
        known,
    )
