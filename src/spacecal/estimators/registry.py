"""The registry of calibration methods: one :class:`EstimatorSpec` per method, in :data:`ESTIMATORS`.

It composes the two halves of :mod:`spacecal.estimators`: :func:`calibrate` runs a method
(:mod:`~spacecal.estimators.methods`) and then assesses its solution
(:mod:`~spacecal.estimators.assessment`); it alone imports both.

Everything the package knows about a method is in its entry: its family, whether its solution
is a likelihood fit (else it gets a bootstrap, and its held-out refits are ML), what it needs
from a recording, the keyword options it takes, a line describing it and where it comes from.
Nothing else lists method names or tells methods apart by name.
"""

from __future__ import annotations

import dataclasses
import enum
from collections.abc import Callable
from typing import Any

from spacecal.core.errors import InvalidInputError, UnknownMethodError
from spacecal.estimators.assessment.report import report_uncertainty
from spacecal.estimators.assessment.without_likelihood import with_bootstrap_uncertainty
from spacecal.estimators.methods.closed_form import (
    HandEyeSolver,
    RobotWorldSolver,
    hand_eye_method,
    robot_world_method,
)
from spacecal.estimators.methods.hand_eye import solve_daniilidis, solve_park, solve_tsai
from spacecal.estimators.methods.kinematic import calibrate_kinematic
from spacecal.estimators.methods.likelihood import calibrate_ml, calibrate_robust
from spacecal.estimators.methods.paper import calibrate_paper
from spacecal.estimators.methods.robot_world import solve_dornaika, solve_li, solve_shah
from spacecal.geometry.transforms import MEASURED_TRANSFORM_ATOL, check_points, check_transform
from spacecal.records import CalibrationResult, NeedleTip, Recording
from spacecal.records.assessment import ErrorThresholds


class Family(enum.Enum):
    """The kind of estimator a method is; the value is the sentence a report shows."""

    PAPER = "the paper's linear-rotation method (sphere and line fits)"
    LIKELIHOOD = "maximum likelihood on the tracker's sphere residuals"
    KINEMATIC = "maximum likelihood with robot kinematic identification"
    ROBOT_WORLD = "closed-form robot-world solver (AX = YB)"
    HAND_EYE = "closed-form hand-eye solver (AX = XB) on relative motions"


class Need(enum.Enum):
    """What a method needs from a recording beyond paired poses; the value is a reader's phrase."""

    SWEEPS = "the paper's six sweeps (segments rot_x .. lin_z)"
    JOINTS = "the joint angles of every used frame"
    ROBOT_MODEL = "the robot model in the recording metadata"
    VARIED_ROTATION = "poses rotating about at least two axes"


@dataclasses.dataclass(frozen=True)
class EstimatorSpec:
    """Everything about one calibration method.

    Attributes
    ----------
    name : str
        The name ``calibrate`` and ``--method`` take, and results carry.
    family : Family
    solve : callable
        ``solve(recording, **options)``: a likelihood method takes ``targets_in_base`` and
        ``needle_tip`` too and returns its :class:`~spacecal.estimators.methods.solution.Solution`
        (the registry assesses it); the others return an unassessed
        :class:`~spacecal.records.CalibrationResult` (the registry bootstraps it and handles
        both options).
    summary : str
        One line on what it does, for reports and listings.
    reference : str
        The publication (and equations) it implements, or the section of ``docs/methods.md``
        that derives it.
    likelihood : bool
        Its solution is the ML fit of its observations: it reports its own covariance and
        predicted TRE, and its held-out refits are its own. Otherwise the registry adds a
        bootstrap covariance over frames and the expected error is cross-validated with ML
        refits (see :attr:`bootstrap`, :attr:`held_out_refit`).
    options : frozenset of str
        The keyword options ``solve`` takes (besides ``recording``, ``targets_in_base`` and
        ``needle_tip``).
    needs : frozenset of Need
        What a recording must hold for it.
    closed_form : callable or None
        The bare solver a closed-form method wraps (:data:`RobotWorldSolver` or
        :data:`HandEyeSolver`); None for the others.
    """

    name: str
    family: Family
    solve: Callable[..., Any]
    summary: str
    reference: str
    likelihood: bool
    options: frozenset[str] = frozenset()
    needs: frozenset[Need] = frozenset()
    closed_form: RobotWorldSolver | HandEyeSolver | None = None

    def __post_init__(self) -> None:
        if not self.name or not self.summary.strip() or not self.reference.strip():
            raise ValueError(f"estimator {self.name!r}: name, summary and reference must be given")
        closed = self.family in (Family.ROBOT_WORLD, Family.HAND_EYE)
        if closed != (self.closed_form is not None):
            raise ValueError(f"estimator {self.name!r}: a closed form is given exactly for the closed forms")

    @property
    def bootstrap(self) -> bool:
        """Its covariance comes from the bootstrap over frames (methods without a likelihood)."""
        return not self.likelihood

    @property
    def held_out_refit(self) -> str:
        """Whose refits cross-validate its expected error: ``"own"`` or ``"ML"``."""
        return "own" if self.likelihood else "ML"


def _spec(*args: Any, **kwargs: Any) -> tuple[str, EstimatorSpec]:
    spec = EstimatorSpec(*args, **kwargs)
    return spec.name, spec


def _closed_form(
    name: str,
    family: Family,
    method: Callable[..., CalibrationResult],
    solver: RobotWorldSolver | HandEyeSolver,
    by: str,
    reference: str,
) -> tuple[str, EstimatorSpec]:
    """The entry of a closed form: no likelihood (bootstrapped), needs rotation about two axes."""
    return _spec(
        name,
        family,
        method,
        f"{family.value} by {by}",
        reference,
        likelihood=False,
        needs=frozenset({Need.VARIED_ROTATION}),
        closed_form=solver,
    )


def _robot_world(name: str, solver: RobotWorldSolver, by: str, reference: str) -> tuple[str, EstimatorSpec]:
    return _closed_form(name, Family.ROBOT_WORLD, robot_world_method(name, solver), solver, by, reference)


def _hand_eye(name: str, solver: HandEyeSolver, by: str, reference: str) -> tuple[str, EstimatorSpec]:
    return _closed_form(name, Family.HAND_EYE, hand_eye_method(name, solver), solver, by, reference)


#: The calibration methods by name, in the order listings show them.
ESTIMATORS: dict[str, EstimatorSpec] = dict(
    [
        _spec(
            "paper",
            Family.PAPER,
            calibrate_paper,
            "the paper's linear-rotation method (sphere and line fits)",
            "Space calibration of the cranial and maxillofacial robotic system in surgery, "
            "section 3 (eqs. 2-9)",
            likelihood=False,
            options=frozenset({"thresholds"}),
            needs=frozenset({Need.SWEEPS}),
        ),
        _spec(
            "ml",
            Family.LIKELIHOOD,
            calibrate_ml,
            "maximum likelihood over all marker poses",
            "docs/methods.md, Maximum likelihood (Levenberg-Marquardt on sphere residuals; "
            "noise components as in Amiri-Simkooei, J. Geodesy 2008)",
            likelihood=True,
            options=frozenset({"sigma_mm", "noise_model", "fitted"}),
            needs=frozenset({Need.VARIED_ROTATION}),
        ),
        _spec(
            "robust",
            Family.LIKELIHOOD,
            calibrate_robust,
            "maximum likelihood with outlier rejection",
            "docs/methods.md, Robust maximum likelihood (RANSAC start, Cauchy IRLS, then ML on the inliers)",
            likelihood=True,
            options=frozenset({"sigma_mm", "seed"}),
            needs=frozenset({Need.VARIED_ROTATION}),
        ),
        _spec(
            "kinematic",
            Family.KINEMATIC,
            calibrate_kinematic,
            "maximum likelihood with robot kinematic identification",
            "docs/methods.md, Kinematic identification (ML jointly with the identifiable DH corrections)",
            likelihood=True,
            options=frozenset(
                {
                    "sigma_mm",
                    "prior_length_sd_mm",
                    "prior_angle_sd_rad",
                    "rank_tolerance",
                    "iterations",
                    "model_selection",
                    "prior_from_data",
                }
            ),
            needs=frozenset({Need.JOINTS, Need.ROBOT_MODEL, Need.VARIED_ROTATION}),
        ),
        _robot_world(
            "shah",
            solve_shah,
            "Shah",
            "Shah 2013, Solving the robot-world/hand-eye calibration problem using the Kronecker "
            "product, J. Mech. Robot. 5(3)",
        ),
        _robot_world(
            "li",
            solve_li,
            "Li, Wang and Wu",
            "Li, Wang, Wu 2010, Simultaneous robot-world and hand-eye calibration using dual-quaternions "
            "and Kronecker product, Int. J. Phys. Sci. 5(10): 1530-1536",
        ),
        _robot_world(
            "dornaika",
            solve_dornaika,
            "Dornaika and Horaud",
            "Dornaika, Horaud 1998, Simultaneous robot-world and hand-eye calibration, IEEE TRA 14(4), "
            "closed-form part",
        ),
        _hand_eye(
            "tsai",
            solve_tsai,
            "Tsai and Lenz",
            "Tsai, Lenz 1989, A new technique for fully autonomous and efficient 3D robotics hand/eye "
            "calibration, IEEE TRA 5(3): 345-358, eqs. 12-15",
        ),
        _hand_eye(
            "park",
            solve_park,
            "Park and Martin",
            "Park, Martin 1994, Robot sensor calibration: solving AX = XB on the Euclidean group, "
            "IEEE TRA 10(5): 717-721, eqs. 11-13",
        ),
        _hand_eye(
            "daniilidis",
            solve_daniilidis,
            "Daniilidis",
            "Daniilidis 1999, Hand-eye calibration using dual quaternions, IJRR 18(3): 286-298, eqs. 31-35",
        ),
    ]
)


def estimator(method: str) -> EstimatorSpec:
    """The registry entry of ``method``.

    Raises
    ------
    UnknownMethodError
        For a name not in the registry; the message lists the valid ones.
    """
    if method not in ESTIMATORS:
        raise UnknownMethodError(f"unknown method {method!r}; valid methods: {', '.join(sorted(ESTIMATORS))}")
    return ESTIMATORS[method]


def estimators_of(*families: Family) -> dict[str, EstimatorSpec]:
    """The entries of the given families, in registry order."""
    return {name: spec for name, spec in ESTIMATORS.items() if spec.family in families}


def calibrate(
    recording: Recording, method: str = "paper", uncertainty: bool = True, **options: Any
) -> CalibrationResult:
    """Estimate ``tracker_from_base`` and ``tcp_from_marker`` from a recording.

    Parameters
    ----------
    recording : Recording
    method : str
        A name from :data:`ESTIMATORS`.
    uncertainty : bool
        For methods without a likelihood, add a bootstrap covariance, predicted TRE, expected
        error and verdict (50 re-solves); Monte Carlo studies switch it off.
    **options
        The method's own options (:attr:`EstimatorSpec.options`), ``targets_in_base`` and
        ``needle_tip`` (a :class:`~spacecal.records.NeedleTip`: the expected error is stated at
        the tip IK aims; any method) and ``error_thresholds``, an
        :class:`~spacecal.records.assessment.ErrorThresholds` the verdict is graded against.

    Raises
    ------
    UnknownMethodError
        For a name not in the registry; the message lists the valid ones.
    InvalidInputError
        For an option the method does not take (naming the methods that do), pose stacks that
        are not rigid transforms (:func:`check_recording_poses`) or targets that are not
        (M, 3) finite points.
    """
    spec = estimator(method)
    thresholds = options.pop("error_thresholds", None)
    if thresholds is not None and not isinstance(thresholds, ErrorThresholds):
        raise InvalidInputError("error_thresholds must be an ErrorThresholds (good, acceptable, poor mm)")
    targets = options.pop("targets_in_base", None)
    if targets is not None:
        targets = check_points(targets, "targets_in_base")
    tip = options.pop("needle_tip", None)
    if tip is not None and not isinstance(tip, NeedleTip):
        raise InvalidInputError("needle_tip must be a NeedleTip (a pivot's tip in the marker frame)")
    check_recording_poses(recording)
    unexpected = sorted(set(options) - spec.options)
    if unexpected:
        takers = sorted(m for m, s in ESTIMATORS.items() if set(unexpected) <= s.options)
        raise InvalidInputError(
            f"method {method!r} does not take {', '.join(unexpected)}"
            + (f" (methods that do: {', '.join(takers)})" if takers else "")
        )
    if spec.likelihood:
        # a likelihood method ends in its solution and covariance; the assessment states the rest
        result = report_uncertainty(
            spec.solve(recording, targets_in_base=targets, needle_tip=tip, **options), thresholds
        )
    else:
        result = spec.solve(recording, **options)
        if uncertainty:
            result = with_bootstrap_uncertainty(result, recording, spec.solve, targets, tip, thresholds)
    if tip is not None and result.needle_tip is None:
        result = result.replace(needle_tip=tip)  # no expected error was asked for
    return result


def check_recording_poses(recording: Recording) -> None:
    """Refuse a recording whose pose stacks are not rigid transforms (one readable line).

    Frames where the marker was not seen are rows of NaN in ``tracker_from_marker_stack``
    and pass; the tolerance is that of measured matrices (about six significant digits).

    Raises
    ------
    InvalidInputError
    """
    check_transform(
        recording.base_from_tcp_stack,
        "recording.base_from_tcp_stack",
        stack=True,
        atol=MEASURED_TRANSFORM_ATOL,
    )
    check_transform(
        recording.tracker_from_marker_stack,
        "recording.tracker_from_marker_stack",
        stack=True,
        allow_missing=True,
        atol=MEASURED_TRANSFORM_ATOL,
    )
