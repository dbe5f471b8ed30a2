"""A method's estimate with its covariance: what the assessment judges.

A likelihood method (``ml``, ``robust``, ``kinematic``) ends here; the registry then states its
expected error, residuals and verdict (:func:`spacecal.estimators.assessment.report.report_uncertainty`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from spacecal.estimators.methods.observations import Observations
from spacecal.geometry.arrays import ArrayLike, FloatArray, IntArray
from spacecal.models.kinematics import RobotModel
from spacecal.records import NeedleTip, Recording

#: What the covariance of a likelihood fit is.
PERTURBATION_NOTE = (
    "perturbations: tracker_from_base = [exp(w) R | t + v] in the tracker frame; "
    "tcp_from_marker = [R exp(w) | t + v] with w in the marker frame; mm, rad"
)


@dataclass(frozen=True)
class Solution:
    """An estimate with its covariance, before the assessment adds what follows from them.

    Attributes
    ----------
    method : str
        The registry name the result carries.
    recording : Recording
    obs : Observations
        The frames the estimate used, with the poses its robot model gives.
    tracker_from_base, tcp_from_marker : numpy.ndarray, shape (4, 4)
        The estimate (mm).
    covariance : numpy.ndarray, shape (12, 12)
        In the ML perturbation parameters (mm, rad).
    variance_factor : float
        A posteriori variance factor at the estimate
        (:func:`spacecal.estimators.methods.likelihood.variance_factor_of`).
    diagnostics : dict
        The estimator's own diagnostics, kept as they are.
    outlier_rows : sequence of int
        Recording rows the estimator rejected as outliers.
    robot_model : RobotModel or None
        The model ``obs`` poses come from (default: the nominal model named in the recording's
        metadata, if any).
    absorbed_dh : sequence of int
        The DH corrections identified with ``robot_model``.
    dh_error_scale_mm : float or None
        The robot's DH error scale when known (see
        :func:`spacecal.estimators.assessment.expected_error.expected_error`).
    likelihood_based : bool
        The solution is the ML fit of its observations (its held-out refits are its own);
        False for the others (the paper's method, the closed forms), whose held-out refits are
        ML and whose distance from the ML solution is added to the expected error.
    covariance_note : str
        What the covariance is, stored beside it.
    targets_in_base : array_like, shape (M, 3), optional
        Points (mm, base frame) at which to predict the TRE, besides the site.
    needle_tip : NeedleTip, optional
        A tip measured by a pivot, which IK aims (the expected error is at it).
    identified_model : RobotModel or None
        The robot model the calibration carries for IK (``kinematic``), None for the others.
    """

    method: str
    recording: Recording
    obs: Observations
    tracker_from_base: FloatArray
    tcp_from_marker: FloatArray
    covariance: FloatArray
    variance_factor: float
    diagnostics: dict[str, Any] = field(default_factory=dict)
    outlier_rows: IntArray | Sequence[int] = ()
    robot_model: RobotModel | None = None
    absorbed_dh: Sequence[int] = ()
    dh_error_scale_mm: float | None = None
    likelihood_based: bool = True
    covariance_note: str = PERTURBATION_NOTE
    targets_in_base: ArrayLike | None = None
    needle_tip: NeedleTip | None = None
    identified_model: RobotModel | None = None
