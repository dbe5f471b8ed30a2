"""Registry methods ``ml`` and ``robust``, and the Cramér–Rao bound on target error."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy.special import chdtri

from spacecal.core.errors import DegenerateDataError, InvalidInputError
from spacecal.estimators.methods.ml import (
    Fit,
    cauchy_weights,
    covariance_from_information,
    frame_errors,
    information_matrix,
    levenberg_marquardt,
    predicted_tre_mm,
)
from spacecal.estimators.methods.noise_model import NoiseModel, fit_with_noise_model
from spacecal.estimators.methods.observations import Observations, build_observations
from spacecal.estimators.methods.robot_world import solve_shah
from spacecal.estimators.methods.samples import site_in_base
from spacecal.estimators.methods.solution import PERTURBATION_NOTE, Solution
from spacecal.geometry.arrays import ArrayLike, BoolArray, FloatArray, IntArray
from spacecal.geometry.metrics import cube_grid
from spacecal.geometry.transforms import invert_transform
from spacecal.records import NeedleTip, Recording

#: Frames beyond this quantile of the inlier error distribution are outliers.
OUTLIER_QUANTILE = 0.999

#: Systematic errors (robot kinematics, tracker volume error) make inlier errors heavier-
#: tailed than Gaussian: in the realistic scenario the largest inlier frame error is about
#: 3.7x the median. Frames within this factor of the median are never called outliers.
SYSTEMATIC_TAIL_FACTOR = 4.0

#: More frames flagged as outliers than this share of the kept ones: not one rigid set-up.
MAX_OUTLIER_FRACTION = 0.25

#: The fewest inliers a robust fit is refined on: the RANSAC subset size, so the refit is
#: over-determined.
ROBUST_FEWEST_INLIERS = 6

#: Side of the cube around the site over which TRE is summarised, mm.
CUBE_SIDE_MM = 200.0


def tre_summary(
    tracker_from_base: FloatArray,
    covariance: FloatArray,
    site: ArrayLike,
    targets_in_base: ArrayLike | None = None,
) -> dict[str, Any]:
    """Predicted TRE at the site, RMS over a 200 mm cube around it, and at given targets."""
    site = np.asarray(site, dtype=float)
    summary: dict[str, Any] = {
        "site_in_base_mm": np.asarray(site).tolist(),
        "site": float(predicted_tre_mm(tracker_from_base, covariance, site[None])[0]),
        "cube_rms": float(
            np.sqrt(
                np.mean(predicted_tre_mm(tracker_from_base, covariance, cube_grid(site, CUBE_SIDE_MM)) ** 2)
            )
        ),
        "cube_side_mm": CUBE_SIDE_MM,
    }
    if targets_in_base is not None:
        targets = np.atleast_2d(np.asarray(targets_in_base, dtype=float))
        summary["targets"] = [
            {"target_in_base_mm": t.tolist(), "tre_mm": float(e)}
            for t, e in zip(targets, predicted_tre_mm(tracker_from_base, covariance, targets))
        ]
    return summary


def _initial_estimate(obs: Observations, recording: Recording) -> tuple[FloatArray, FloatArray]:
    tcp_from_marker, base_from_tracker = solve_shah(
        obs.base_from_tcp_stack, recording.tracker_from_marker_stack[obs.rows]
    )
    return invert_transform(base_from_tracker), tcp_from_marker


def variance_factor_of(
    obs: Observations, tracker_from_base: FloatArray, tcp_from_marker: FloatArray
) -> float:
    """A posteriori variance factor: chi-square of the sphere residuals over its degrees of freedom."""
    errors = frame_errors(obs, tracker_from_base, tcp_from_marker)
    dof = max(obs.dof_per_frame * len(obs.rows) - 12, 1)
    return float(np.sum(errors**2) * len(obs.spheres_in_marker) / obs.sigma_mm**2) / dof


def residual_noise_level(
    obs: Observations, tracker_from_base: FloatArray, tcp_from_marker: FloatArray
) -> float:
    """The per-axis sphere noise (mm) the fit's residuals show: ``obs.sigma_mm`` scaled by the
    square root of :func:`variance_factor_of`, which holds whatever systematic error the fit
    leaves as well. For a recording without a known noise level (no tracker fit RMS), whose
    ``sigma_mm`` is only a placeholder."""
    return float(obs.sigma_mm * np.sqrt(variance_factor_of(obs, tracker_from_base, tcp_from_marker)))


def _package(
    method: str,
    recording: Recording,
    obs: Observations,
    tracker_from_base: FloatArray,
    tcp_from_marker: FloatArray,
    targets_in_base: ArrayLike | None,
    extra: dict[str, Any],
    outlier_rows: IntArray | Sequence[int] = (),
    noise_information: FloatArray | None = None,
    needle_tip: NeedleTip | None = None,
) -> Solution:
    variance_factor = variance_factor_of(obs, tracker_from_base, tcp_from_marker)
    if noise_information is not None:
        # the estimated variance components already carry the residuals' scale
        information = noise_information
        covariance = covariance_from_information(information)
    else:
        information = information_matrix(obs, tracker_from_base, tcp_from_marker)
        # Without a known tracker noise the residuals alone set the scale (no floor at 1).
        scale = max(variance_factor, 1.0) if obs.sigma_known else variance_factor
        covariance = covariance_from_information(information) * scale
    eigenvalues = np.linalg.eigvalsh(information)
    extra = {
        "conditioning": {
            "information_eigenvalues": eigenvalues.tolist(),
            "condition_number": float(eigenvalues.max() / eigenvalues.min()),
        },
        **extra,
    }
    # this is the ML fit of obs: its held-out refits are its own
    return Solution(
        method,
        recording,
        obs,
        tracker_from_base,
        tcp_from_marker,
        covariance,
        variance_factor,
        extra,
        outlier_rows,
        likelihood_based=True,
        covariance_note=PERTURBATION_NOTE,
        targets_in_base=targets_in_base,
        needle_tip=needle_tip,
    )


#: Choices of ``calibrate(recording, "ml", noise_model=...)``.
NOISE_MODELS = ("estimated", "isotropic")


def calibrate_ml(
    recording: Recording,
    sigma_mm: float | None = None,
    targets_in_base: ArrayLike | None = None,
    noise_model: str = "estimated",
    fitted: tuple[Observations, Fit] | None = None,
    needle_tip: NeedleTip | None = None,
) -> Solution:
    """Maximum-likelihood ``tracker_from_base`` and ``tcp_from_marker`` from every visible frame.

    Starts from Shah's closed form, then Levenberg–Marquardt on sphere residuals (see
    :mod:`spacecal.estimators.methods.ml`). Sweeps and static poses count alike. With the default
    ``noise_model="estimated"`` the fit is then re-weighted by variance components learnt
    from its residuals (lateral and depth tracker noise, and for pose-only data an orientation
    noise; :mod:`spacecal.estimators.methods.noise_model`), and the covariance and predicted TRE use
    them.

    Parameters
    ----------
    recording : Recording
    sigma_mm : float, optional
        Per-axis sphere noise; estimated from the tracker's RMS fit errors if omitted. It sets
        the variance factor (the verdict's test for systematic error) and, for
        ``noise_model="isotropic"``, the weights.
    targets_in_base : array_like, shape (M, 3), optional
        Points (mm, base frame) at which to predict the TRE, besides the site.
    noise_model : {"estimated", "isotropic"}
        ``"isotropic"``: one sigma for every sphere coordinate, as before.
    fitted : (Observations, Fit), optional
        :func:`fit_ml`'s result for this recording and ``sigma_mm``, when the caller has it
        already (it is not fitted again).
    needle_tip : NeedleTip, optional
        A tip measured by a pivot, which IK aims: the expected error is stated at it.

    Raises
    ------
    InvalidInputError
        For an unknown ``noise_model``.
    """
    if noise_model not in NOISE_MODELS:
        raise InvalidInputError(f"noise_model must be one of {', '.join(NOISE_MODELS)}, got {noise_model!r}")
    obs, fit = fitted if fitted is not None else fit_ml(recording, sigma_mm)
    extra: dict[str, Any] = {"iterations": fit.iterations, "converged": fit.converged}
    if noise_model == "isotropic":
        return _package(
            "ml",
            recording,
            obs,
            fit.tracker_from_base,
            fit.tcp_from_marker,
            targets_in_base,
            extra,
            needle_tip=needle_tip,
        )
    model = reweighted_by_noise_model(recording, obs, fit.tracker_from_base, fit.tcp_from_marker)
    return _package(
        "ml",
        recording,
        obs,
        model.tracker_from_base,
        model.tcp_from_marker,
        targets_in_base,
        {**extra, "noise_model": model.summary()},
        noise_information=model.information,
        needle_tip=needle_tip,
    )


def reweighted_by_noise_model(
    recording: Recording, obs: Observations, tracker_from_base: FloatArray, tcp_from_marker: FloatArray
) -> NoiseModel:
    """The fit re-weighted by the tracker noise's variance components learnt from its residuals
    (:mod:`spacecal.estimators.methods.noise_model`), from a plain LM solution of ``obs``.

    Raises
    ------
    DegenerateDataError
        When the problem is unidentifiable (refused with its reason before any re-weighting) or
        the components cannot be estimated from these frames.
    """
    covariance_from_information(information_matrix(obs, tracker_from_base, tcp_from_marker))
    try:
        return fit_with_noise_model(
            obs, recording.tracker_from_marker_stack[obs.rows], tracker_from_base, tcp_from_marker
        )
    except np.linalg.LinAlgError as exc:
        raise DegenerateDataError(f"noise components cannot be estimated from these frames ({exc})") from exc


def fit_ml(recording: Recording, sigma_mm: float | None = None) -> tuple[Observations, Fit]:
    """The bare maximum-likelihood fit (Shah start, then Levenberg–Marquardt), without the
    diagnostics a result carries: for callers that fit many times (clock-offset search)."""
    obs = build_observations(recording, sigma_mm=sigma_mm)
    start_tracker_from_base, start_tcp_from_marker = _initial_estimate(obs, recording)
    return obs, levenberg_marquardt(obs, start_tracker_from_base, start_tcp_from_marker)


def frame_error_sigma(errors: FloatArray, dof: int, quantile: float = 0.5) -> float:
    """The per-axis noise (mm) a quantile of the frame errors gives: an inlier's squared frame
    error is sigma^2 chi2(dof) / K. A lower ``quantile`` reads it off the better frames, which
    bad frames up to ``1 - quantile`` cannot inflate."""
    value = float(np.quantile(errors, quantile))
    return value / float(np.sqrt(chdtri(dof, 1.0 - quantile) / dof))  # chdtri: upper-tail inverse


def outlier_cutoff(errors: FloatArray, dof: int, quantile: float = 0.5) -> float:
    """The frame error (mm) beyond which a frame is an outlier, from the errors' own spread.

    :data:`OUTLIER_QUANTILE` of the chi-square distribution :func:`frame_error_sigma` gives
    bounds an inlier; systematic errors make the tail heavier, so never less than
    :data:`SYSTEMATIC_TAIL_FACTOR` times the median that sigma implies.
    """
    sigma = frame_error_sigma(errors, dof, quantile)
    median = sigma * np.sqrt(chdtri(dof, 0.5) / dof)
    gaussian = sigma * np.sqrt(chdtri(dof, 1.0 - OUTLIER_QUANTILE) / dof)
    return float(max(gaussian, SYSTEMATIC_TAIL_FACTOR * median))


def ransac_start(
    obs: Observations,
    recording: Recording,
    rng: np.random.Generator,
    iterations: int = 60,
    subset: int = 6,
    threshold_mm: float | None = None,
) -> tuple[tuple[FloatArray, FloatArray], BoolArray, float]:
    """Best closed-form (Shah) solution over random frame subsets.

    With a bound given, or a noise level the tracker measured (its fit RMS), a frame within
    ``max(1 mm, 10 sigma)`` is an inlier and the subset with the most inliers wins. Without
    one, no fixed bound fits every tracker (a camera's noise is mm, an optical tracker's a tenth
    of that): the subset whose frames' median error is least wins (least median of squares,
    which fewer than half bad frames cannot move), refined on its better half, and the inliers
    are the frames within :func:`outlier_cutoff` of its errors' lower quartile.

    Returns the transforms, the inlier mask and the threshold used.
    """
    by_count = threshold_mm is not None or obs.sigma_known
    threshold = threshold_mm if threshold_mm is not None else max(1.0, 10.0 * obs.sigma_mm)
    poses = recording.tracker_from_marker_stack[obs.rows]
    best_score, best_start, best_errors = -np.inf, None, None
    for _ in range(iterations):
        pick = rng.choice(len(obs.rows), size=min(subset, len(obs.rows)), replace=False)
        try:
            tcp_from_marker, base_from_tracker = solve_shah(obs.base_from_tcp_stack[pick], poses[pick])
        except DegenerateDataError:
            continue
        tracker_from_base = invert_transform(base_from_tracker)
        errors = frame_errors(obs, tracker_from_base, tcp_from_marker)
        score = float(np.sum(errors < threshold)) if by_count else -float(np.median(errors))
        if score > best_score:
            best_score, best_start, best_errors = score, (tracker_from_base, tcp_from_marker), errors
    if best_start is None or best_errors is None:
        raise DegenerateDataError("no random subset of frames gave a usable closed-form start")
    if not by_count:
        # refined on its better half, so the errors are the noise's and not the 6-frame
        # subset's own error; the noise level is read off their lower quartile (the better
        # half's median), which even half the frames bad cannot inflate, so such a recording
        # finds no majority and is refused rather than fitted through its bad frames
        better_half = (best_errors <= np.median(best_errors)).astype(float)
        fit = levenberg_marquardt(obs, *best_start, frame_weights=better_half)
        best_start = (fit.tracker_from_base, fit.tcp_from_marker)
        best_errors = frame_errors(obs, *best_start)
        threshold = outlier_cutoff(best_errors, obs.dof_per_frame, quantile=0.25)
    return best_start, best_errors < threshold, threshold


def calibrate_robust(
    recording: Recording,
    sigma_mm: float | None = None,
    targets_in_base: ArrayLike | None = None,
    seed: int = 0,
    needle_tip: NeedleTip | None = None,
) -> Solution:
    """Maximum likelihood that survives bad frames (mis-detected spheres, stale frames, reflections).

    1. RANSAC-style start: Shah's closed form on random 6-frame subsets (:func:`ransac_start`:
       most frames within max(1 mm, 10 sigma) where the noise level is known, else the least
       median frame error), refined on its inliers.
    2. Iteratively reweighted LM with the Cauchy loss on per-frame errors, scaled by a
       robust (median) estimate of the inlier error.
    3. Frames beyond both the 99.9 % chi-square bound of that scale (6 degrees of freedom
       per fitted pose, 3K for raw spheres) and 4x the median frame error are flagged, with
       their error, and ML on the rest (re-weighted by the learnt noise components, as
       ``ml`` is) gives the efficient estimate and covariance.
    """
    obs = build_observations(recording, sigma_mm=sigma_mm)
    rng = np.random.default_rng(seed)
    (start_tracker_from_base, start_tcp_from_marker), inliers, threshold = ransac_start(obs, recording, rng)
    if inliers.sum() <= len(obs.rows) / 2 or inliers.sum() < ROBUST_FEWEST_INLIERS:
        # the frames agree on no single calibration (units, pose conventions, pairing?): a
        # robust fit needs its inliers to be the majority, whatever the recording's length
        raise DegenerateDataError(
            f"only {int(inliers.sum())} of {len(obs.rows)} frames agree with any closed-form start "
            "(a majority is needed): the recording does not describe one rigid set-up"
        )
    fit = levenberg_marquardt(
        obs, start_tracker_from_base, start_tcp_from_marker, frame_weights=inliers.astype(float)
    )
    tracker_from_base, tcp_from_marker = fit.tracker_from_base, fit.tcp_from_marker
    # An inlier's squared frame error is sigma^2 chi2(dof) / K: scale the errors by a
    # robust (median) estimate of sigma, so systematic errors larger than the tracker's
    # noise do not turn good frames into outliers.
    for _ in range(5):
        errors = frame_errors(obs, tracker_from_base, tcp_from_marker)
        weights = cauchy_weights(errors / frame_error_sigma(errors, obs.dof_per_frame))
        fit = levenberg_marquardt(obs, tracker_from_base, tcp_from_marker, frame_weights=weights)
        tracker_from_base, tcp_from_marker = fit.tracker_from_base, fit.tcp_from_marker
    errors = frame_errors(obs, tracker_from_base, tcp_from_marker)
    cutoff = outlier_cutoff(errors, obs.dof_per_frame)
    keep = errors <= cutoff
    outlier_rows = obs.rows[~keep]
    # the noise level of all frames where it is known (a given sigma, the tracker's fit RMS);
    # without either, the kept frames' own noise is unknown too, never the 1 mm placeholder
    kept = build_observations(
        recording,
        mask=np.isin(np.arange(len(recording)), obs.rows[keep]),
        sigma_mm=obs.sigma_mm if obs.sigma_known else None,
    )
    # ML on the kept frames, re-weighted by the noise's components as ``ml`` is
    final = levenberg_marquardt(kept, tracker_from_base, tcp_from_marker)
    model = reweighted_by_noise_model(recording, kept, final.tracker_from_base, final.tcp_from_marker)
    outliers = [
        {
            "row": int(r),
            "time_s": float(recording.time_s[r]),
            "segment": str(recording.segment[r]),
            "error_mm": float(e),
            "reason": f"frame error {e:.2f} mm > {cutoff:.2f} mm "
            "(the larger of the 99.9 % Gaussian bound and 4x the median frame error)",
        }
        for r, e in zip(outlier_rows, errors[~keep])
    ]
    return _package(
        "robust",
        recording,
        kept,
        model.tracker_from_base,
        model.tcp_from_marker,
        targets_in_base,
        {
            "outliers": outliers,
            "ransac_threshold_mm": threshold,
            "outlier_cutoff_mm": float(cutoff),
            "noise_model": model.summary(),
        },
        outlier_rows,
        noise_information=model.information,
        needle_tip=needle_tip,
    )


def tre_lower_bound(
    recording: Recording,
    tracker_from_base: FloatArray,
    tcp_from_marker: FloatArray,
    sigma_mm: float,
    targets_in_base: ArrayLike | None = None,
) -> dict[str, Any]:
    """Cramér–Rao lower bound on the RMS TRE for a recording under white sphere noise.

    The Fisher information of the 12 parameters is J^T J / sigma^2 with J evaluated at
    the given transforms (the truth in simulation, an estimate otherwise); any unbiased
    estimator's TRE covariance at a point is at least G I^-1 G^T.

    Returns
    -------
    dict
        ``site``, ``cube_rms`` (mm) and per-target bounds as in :func:`tre_summary`.
    """
    obs = build_observations(recording, sigma_mm=sigma_mm)
    covariance = covariance_from_information(information_matrix(obs, tracker_from_base, tcp_from_marker))
    site = site_in_base(recording, obs.rows)
    return tre_summary(tracker_from_base, covariance, site, targets_in_base)
