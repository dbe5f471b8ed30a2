"""Result records of the verification experiment, the pre-operative check, the phantom
experiment and landmark registration: validated on construction, with readers and writers."""

from __future__ import annotations

import datetime
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from spacecal.core.errors import InvalidInputError
from spacecal.core.text import sanitize_for_terminal
from spacecal.geometry.metrics import summary_statistics
from spacecal.records.fields import (
    as_array,
    as_covariance,
    as_transform,
    as_transform_stack,
    check_schema,
    get_mapping,
    get_number,
    get_str,
    plain,
)

#: What measured a verification in the simulator: its laser tracker, which sees the true pose.
SIMULATED_LASER_TRACKER = "the simulator's laser tracker (the true reached pose)"


def _list_of_objects(data: Mapping[str, Any], key: str, what: str) -> list[Mapping[str, Any]]:
    items = data.get(key)
    if not isinstance(items, list) or not all(isinstance(item, Mapping) for item in items):
        raise InvalidInputError(f"{what}: {key!r} must be a list of objects")
    return items


def _column(items: Sequence[Mapping[str, Any]], key: str, what: str) -> np.ndarray:
    return np.array([get_number(item, key, what) for item in items], dtype=float)


def _finite(values: Any, name: str, what: str) -> np.ndarray:
    return as_array(values, (None,), name, what)


@dataclass(frozen=True)
class VerificationResult:
    """Outcome of a verification experiment (paper §5.2).

    Schema history (schema ``spacecal.verification``): 1 had no ``simulated``; 2 added it; 3
    added ``measured_by`` and ``devices``; 4 added ``interrupted`` and ``poses_planned`` (a
    verification stopped before its last pose keeps the poses it measured). Every version is
    read (1 and 2 were measured in the simulator by its laser tracker; 1 to 3 were complete).

    Attributes
    ----------
    desired_tracker_from_needle, reached_tracker_from_needle : numpy.ndarray, shape (N, 4, 4)
        Target and measured needle poses in the tracker frame, mm.
    joints_rad : numpy.ndarray, shape (N, 6)
        The configurations commanded (NaN when read from a file that does not keep them).
    position_error_mm, posture_error_deg : numpy.ndarray, shape (N,)
    simulated : bool
        True when the poses were reached and measured in spacecal's simulator.
    scenario : str
        The simulated scenario's name (simulated results only).
    measured_by : str
        What measured the reached poses, as every figure of it names its source: the
        simulator's laser tracker (the truth), "calibrated marker" (the marker that was
        calibrated measures its own pose: not independent of the calibration's marker_from_tcp),
        "reference tool NAME" (a tracked tool on the needle guide with its own definition), or
        an external measurement file.
    devices : dict of str to str
        The devices the poses were reached and measured on, as they named themselves.
    interrupted : str
        Why the verification stopped before its last pose (a device fault, Ctrl-C, a stop);
        empty when every pose planned was measured.
    poses_planned : int or None
        The poses the verification planned (None: as many as were measured).
    """

    desired_tracker_from_needle: np.ndarray
    reached_tracker_from_needle: np.ndarray
    joints_rad: np.ndarray
    position_error_mm: np.ndarray
    posture_error_deg: np.ndarray
    simulated: bool = True
    scenario: str = ""
    measured_by: str = SIMULATED_LASER_TRACKER
    devices: Mapping[str, str] = field(default_factory=dict)
    interrupted: str = ""
    poses_planned: int | None = None

    SCHEMA = "spacecal.verification"
    SCHEMA_VERSION = 4

    def __post_init__(self) -> None:
        what = "verification"
        n = len(self.position_error_mm)
        object.__setattr__(
            self, "position_error_mm", _finite(self.position_error_mm, "position_error_mm", what)
        )
        object.__setattr__(
            self, "posture_error_deg", _finite(self.posture_error_deg, "posture_error_deg", what)
        )
        if n == 0 or len(self.posture_error_deg) != n:
            raise InvalidInputError(f"{what}: needs one position and one posture error per point (got {n})")
        for name in ("desired_tracker_from_needle", "reached_tracker_from_needle"):
            stack = as_transform_stack(getattr(self, name), name, what)
            if len(stack) != n:
                raise InvalidInputError(f"{what}: {name} has {len(stack)} poses for {n} points")
            object.__setattr__(self, name, stack)

    def statistics(self) -> dict[str, dict[str, float]]:
        """min / mean / max / RMS of both errors."""
        return {
            "position_mm": summary_statistics(self.position_error_mm),
            "posture_deg": summary_statistics(self.posture_error_deg),
        }

    def to_dict(self) -> dict[str, Any]:
        n_points = len(self.position_error_mm)
        return plain(
            {
                "schema": self.SCHEMA,
                "schema_version": self.SCHEMA_VERSION,
                "units": {"length": "mm", "angle": "deg"},
                "simulated": self.simulated,
                "scenario": self.scenario,
                "measured_by": self.measured_by,
                "devices": dict(self.devices),
                "interrupted": self.interrupted or None,
                "poses_planned": self.poses_planned if self.poses_planned is not None else n_points,
                "statistics": self.statistics(),
                "points": [
                    {
                        "desired_tracker_from_needle": d,
                        "reached_tracker_from_needle": r,
                        "joints_rad": None if not np.all(np.isfinite(q)) else q,
                        "position_error_mm": float(p),
                        "posture_error_deg": float(a),
                    }
                    for d, r, q, p, a in zip(
                        self.desired_tracker_from_needle,
                        self.reached_tracker_from_needle,
                        self.joints_rad,
                        self.position_error_mm,
                        self.posture_error_deg,
                    )
                ],
            }
        )

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], what: str = "verification") -> VerificationResult:
        """Read a verification file, version 1 (no ``simulated`` field: it was always
        simulated) to 4 (before 4, every pose planned was measured)."""
        check_schema(data, cls.SCHEMA, (1, 2, 3, 4), what)
        points = _list_of_objects(data, "points", what)
        if not points:
            raise InvalidInputError(f"{what}: 'points' is empty")
        joints = [
            as_array(p["joints_rad"], (6,), "joints_rad", what)
            if p.get("joints_rad") is not None
            else np.full(6, np.nan)
            for p in points
        ]
        simulated = data.get("simulated", True)
        if not isinstance(simulated, bool):
            raise InvalidInputError(f"{what}: 'simulated' must be true or false")
        interrupted = data.get("interrupted")
        if interrupted is not None and not (isinstance(interrupted, str) and len(interrupted) <= 1000):
            raise InvalidInputError(f"{what}: 'interrupted' must be null or a short text")
        planned = data.get("poses_planned", len(points))
        if isinstance(planned, bool) or not isinstance(planned, int) or not len(points) <= planned <= 100_000:
            raise InvalidInputError(
                f"{what}: 'poses_planned' must be a whole number no smaller than the {len(points)} points"
            )
        return cls(
            desired_tracker_from_needle=np.array(
                [
                    as_transform(p.get("desired_tracker_from_needle"), "desired_tracker_from_needle", what)
                    for p in points
                ]
            ),
            reached_tracker_from_needle=np.array(
                [
                    as_transform(p.get("reached_tracker_from_needle"), "reached_tracker_from_needle", what)
                    for p in points
                ]
            ),
            joints_rad=np.array(joints),
            position_error_mm=_column(points, "position_error_mm", what),
            posture_error_deg=_column(points, "posture_error_deg", what),
            simulated=simulated,
            scenario=get_str(data, "scenario", what, default=""),
            measured_by=get_str(data, "measured_by", what, default=SIMULATED_LASER_TRACKER),
            devices=_string_map(data.get("devices"), "devices", what),
            interrupted=interrupted or "",
            poses_planned=None if planned == len(points) and not interrupted else planned,
        )


def _string_map(value: Any, name: str, what: str) -> dict[str, str]:
    """A mapping of short printable texts (device names) from a file; absent: empty."""
    if value is None:
        return {}
    if not isinstance(value, Mapping) or not all(
        isinstance(k, str) and isinstance(v, str) and len(k) <= 100 and len(v) <= 500
        for k, v in value.items()
    ):
        raise InvalidInputError(f"{what}: '{name}' must map names to texts")
    return {k: sanitize_for_terminal(v, 500) for k, v in value.items()}


@dataclass(frozen=True)
class CheckResult:
    """Outcome of a calibration check (one entry of the check history).

    Schema history (``schema: spacecal.check``): 1 had no schema fields and no ``simulated``;
    2 added them; 3 added, per pose, the misfit the calibration left there (predicted from its
    recording), the misfit measured and their tolerance, and the thresholds' ``basis``. Lines
    of every version are read.

    Attributes
    ----------
    tcp_error_mm, rotation_error_deg : numpy.ndarray, shape (P,)
        Per checked pose, the error judged: how far the measured misfit lies from the expected
        one when the check predicted it (``expected_misfit_mm``), else the whole TCP distance
        and marker rotation between the calibration and the tracker.
    threshold_mm, threshold_deg : float
        The largest error that passes (with per-pose tolerances, the largest of them).
    labels : list of str
    simulated : bool or None
        True: checked in the simulator; False: on real devices; None: against a recording.
    devices : dict
        Robot and tracker identities, or the recording checked against.
    checked_utc : str
    misfit_mm, expected_misfit_mm : numpy.ndarray, shape (P, 3), optional
        Measured and expected TCP misfit per pose (where the tracked marker puts the TCP minus
        where the calibration puts it), tracker frame, mm.
    misfit_deg, expected_misfit_deg : numpy.ndarray, shape (P, 3), optional
        Measured and expected marker rotation misfit per pose (rotation vector), tracker frame, deg.
    tolerance_mm, tolerance_deg : numpy.ndarray, shape (P,), optional
        Per pose, the largest departure from the expected misfit that passes.
    basis : str
        How the thresholds came about.
    """

    tcp_error_mm: np.ndarray
    rotation_error_deg: np.ndarray
    threshold_mm: float
    threshold_deg: float
    labels: list[str] = field(default_factory=list)
    simulated: bool | None = None
    devices: dict[str, Any] = field(default_factory=dict)
    checked_utc: str = field(
        default_factory=lambda: datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    )
    misfit_mm: np.ndarray | None = None
    expected_misfit_mm: np.ndarray | None = None
    tolerance_mm: np.ndarray | None = None
    misfit_deg: np.ndarray | None = None
    expected_misfit_deg: np.ndarray | None = None
    tolerance_deg: np.ndarray | None = None
    basis: str = ""

    #: The per-pose fields of schema 3: all present or none.
    EXPECTATION_FIELDS = (
        "misfit_mm",
        "expected_misfit_mm",
        "tolerance_mm",
        "misfit_deg",
        "expected_misfit_deg",
        "tolerance_deg",
    )

    def __post_init__(self) -> None:
        what = "check"
        object.__setattr__(self, "tcp_error_mm", _finite(self.tcp_error_mm, "tcp_error_mm", what))
        object.__setattr__(
            self, "rotation_error_deg", _finite(self.rotation_error_deg, "rotation_error_deg", what)
        )
        present = [getattr(self, name) is not None for name in self.EXPECTATION_FIELDS]
        if any(present) and not all(present):
            raise InvalidInputError(
                f"{what}: give all of {', '.join(self.EXPECTATION_FIELDS)} or none of them"
            )
        if all(present):
            poses = len(self.tcp_error_mm)
            for name in self.EXPECTATION_FIELDS:
                shape = (poses,) if name.startswith("tolerance") else (poses, 3)
                object.__setattr__(self, name, as_array(getattr(self, name), shape, name, what))
            for name in ("tolerance_mm", "tolerance_deg"):
                if not np.all(getattr(self, name) > 0):
                    raise InvalidInputError(f"{what}: {name} must be positive")
        for name in ("threshold_mm", "threshold_deg"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and np.isfinite(value) and value > 0):
                raise InvalidInputError(f"{what}: {name} must be a positive number, got {value!r}")
        if not self.labels:
            object.__setattr__(self, "labels", [f"pose {k + 1}" for k in range(len(self.tcp_error_mm))])
        if not (len(self.labels) == len(self.tcp_error_mm) == len(self.rotation_error_deg)):
            raise InvalidInputError(f"{what}: one label, TCP error and rotation error per pose")

    @property
    def has_expectations(self) -> bool:
        """The check predicted each pose's misfit (schema 3 with expectations)."""
        return self.tolerance_mm is not None

    @property
    def passed(self) -> bool:
        if self.tolerance_mm is not None and self.tolerance_deg is not None:
            return bool(
                np.all(self.tcp_error_mm <= self.tolerance_mm)
                and np.all(self.rotation_error_deg <= self.tolerance_deg)
            )
        return bool(
            np.all(self.tcp_error_mm <= self.threshold_mm)
            and np.all(self.rotation_error_deg <= self.threshold_deg)
        )

    def _pose_dict(self, k: int) -> dict[str, Any]:
        entry: dict[str, Any] = {
            "label": self.labels[k],
            "tcp_error_mm": float(self.tcp_error_mm[k]),
            "rotation_error_deg": float(self.rotation_error_deg[k]),
        }
        if self.has_expectations:
            for name in self.EXPECTATION_FIELDS:
                value = getattr(self, name)[k]
                entry[name] = float(value) if np.ndim(value) == 0 else [float(v) for v in value]
        return entry

    def to_dict(self) -> dict[str, Any]:
        return plain(
            {
                "schema": "spacecal.check",
                "schema_version": 3,
                "checked_utc": self.checked_utc,
                "passed": self.passed,
                "simulated": self.simulated,
                "devices": self.devices,
                "threshold_mm": self.threshold_mm,
                "threshold_deg": self.threshold_deg,
                "basis": self.basis,
                "poses": [self._pose_dict(k) for k in range(len(self.labels))],
            }
        )

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], what: str = "check") -> CheckResult:
        """One history line, version 1 (no schema fields, no ``simulated``), 2 or 3."""
        check_schema(data, "spacecal.check", (1, 2, 3), what)
        poses = _list_of_objects(data, "poses", what)
        simulated = data.get("simulated")
        if simulated is not None and not isinstance(simulated, bool):
            raise InvalidInputError(f"{what}: 'simulated' must be true, false or null")
        devices = data.get("devices") or {}
        if not isinstance(devices, Mapping):
            raise InvalidInputError(f"{what}: 'devices' must be an object")
        return cls(
            tcp_error_mm=_column(poses, "tcp_error_mm", what),
            rotation_error_deg=_column(poses, "rotation_error_deg", what),
            threshold_mm=get_number(data, "threshold_mm", what),
            threshold_deg=get_number(data, "threshold_deg", what),
            labels=[get_str(p, "label", what, default=f"pose {k + 1}") for k, p in enumerate(poses)],
            simulated=simulated,
            devices=dict(devices),
            checked_utc=get_str(data, "checked_utc", what, default=""),
            basis=get_str(data, "basis", what, default=""),
            **_expectations(poses, what),
        )


def _expectations(poses: Sequence[Mapping[str, Any]], what: str) -> dict[str, np.ndarray]:
    """The per-pose expectation fields of a schema-3 history line (none in older lines)."""
    if not poses or "expected_misfit_mm" not in poses[0]:
        return {}
    values = {}
    for name in CheckResult.EXPECTATION_FIELDS:
        if name.startswith("tolerance"):
            values[name] = _column(poses, name, what)
        else:
            values[name] = as_array([p.get(name) for p in poses], (len(poses), 3), name, what)
    return values


@dataclass(frozen=True)
class PhantomResult:
    """Per-case errors of the phantom experiment (paper §5.3), in simulation.

    Attributes
    ----------
    entry_error_mm, target_error_mm, direction_error_deg : numpy.ndarray, shape (C,)
    predicted : list of dict
        Per case: predicted ``entry_mm``, ``target_mm``, ``direction_deg`` and their parts.
    registration_fre_rms_mm : float
    method : str
        Calibration method used.
    paths_refused : int
        Planned paths refused (unreachable or hiding the marker) and replaced.
    reported : list of dict
        On the devices (``spacecal phantom --robot sim --tracker sim``): per case, the errors
        ``guide`` reported (``entry_mm``, ``target_mm``, ``direction_deg``), measured by the
        calibrated marker; empty for the experiment without devices.
    devices : dict
        On the devices: what ran it (the robot and tracker, the work folder with the files each
        step wrote); empty without devices.
    """

    entry_error_mm: np.ndarray
    target_error_mm: np.ndarray
    direction_error_deg: np.ndarray
    predicted: list[dict[str, Any]]
    registration_fre_rms_mm: float
    method: str
    paths_refused: int = 0
    reported: list[dict[str, Any]] = field(default_factory=list)
    devices: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        what = "phantom"
        for name in ("entry_error_mm", "target_error_mm", "direction_error_deg"):
            object.__setattr__(self, name, _finite(getattr(self, name), name, what))
        if not (len(self.entry_error_mm) == len(self.target_error_mm) == len(self.direction_error_deg)):
            raise InvalidInputError(f"{what}: one entry, target and direction error per case")
        if self.reported and len(self.reported) != len(self.entry_error_mm):
            raise InvalidInputError(f"{what}: one reported error per case, or none")

    def statistics(self) -> dict[str, dict[str, float]]:
        return {
            "entry_mm": summary_statistics(self.entry_error_mm),
            "target_mm": summary_statistics(self.target_error_mm),
            "direction_deg": summary_statistics(self.direction_error_deg),
        }

    def to_dict(self) -> dict[str, Any]:
        return plain(
            {
                "schema": "spacecal.phantom",
                "schema_version": 1,
                "simulated": True,
                "method": self.method,
                "statistics": self.statistics(),
                "registration_fre_rms_mm": self.registration_fre_rms_mm,
                "paths_refused": self.paths_refused,
                **({"devices": self.devices} if self.devices else {}),
                "cases": [
                    {
                        "entry_error_mm": float(e),
                        "target_error_mm": float(t),
                        "direction_error_deg": float(d),
                        "predicted": p,
                        **({"reported": self.reported[k]} if self.reported else {}),
                    }
                    for k, (e, t, d, p) in enumerate(
                        zip(
                            self.entry_error_mm,
                            self.target_error_mm,
                            self.direction_error_deg,
                            self.predicted,
                        )
                    )
                ],
            }
        )

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], what: str = "phantom") -> PhantomResult:
        check_schema(data, "spacecal.phantom", (1,), what)
        cases = _list_of_objects(data, "cases", what)
        return cls(
            entry_error_mm=_column(cases, "entry_error_mm", what),
            target_error_mm=_column(cases, "target_error_mm", what),
            direction_error_deg=_column(cases, "direction_error_deg", what),
            predicted=[dict(c.get("predicted") or {}) for c in cases],
            registration_fre_rms_mm=get_number(data, "registration_fre_rms_mm", what),
            method=get_str(data, "method", what, default="unknown"),
            paths_refused=int(get_number(data, "paths_refused", what, default=0.0)),
            reported=[dict(c["reported"]) for c in cases if isinstance(c.get("reported"), Mapping)],
            devices=dict(get_mapping(data, "devices", what, {})),
        )


@dataclass(frozen=True)
class LandmarkRegistrationResult:
    """A landmark registration and what it was computed from.

    Attributes
    ----------
    reference_from_phantom : numpy.ndarray, shape (4, 4)
        Maps phantom (image/landmark) coordinates into the reference marker's frame, mm.
    detected_in_reference : numpy.ndarray, shape (M, 3)
        Landmarks as detected with the stylus, in the reference frame, mm.
    detected_at_s : list of float
        Time of each detection.
    residuals_mm : numpy.ndarray, shape (M,)
        Per-landmark registration error, mm.
    fre_rms_mm, fre_mean_mm, fle_rms_mm : float
        Fiducial registration error (RMS, mean: PLUS's "Error") and the localisation error it implies.
    """

    reference_from_phantom: np.ndarray
    detected_in_reference: np.ndarray
    detected_at_s: list[float]
    residuals_mm: np.ndarray
    fre_rms_mm: float
    fre_mean_mm: float
    fle_rms_mm: float

    def __post_init__(self) -> None:
        what = "landmark registration"
        object.__setattr__(
            self,
            "reference_from_phantom",
            as_transform(self.reference_from_phantom, "reference_from_phantom", what),
        )
        object.__setattr__(
            self,
            "detected_in_reference",
            as_array(self.detected_in_reference, (None, 3), "detected_in_reference", what),
        )
        object.__setattr__(self, "residuals_mm", _finite(self.residuals_mm, "residuals_mm", what))

    def to_dict(self) -> dict[str, Any]:
        return plain(
            {
                "schema": "spacecal.landmark_registration",
                "schema_version": 1,
                "units": {"length": "mm"},
                "reference_from_phantom": self.reference_from_phantom,
                "landmarks_detected_in_reference_mm": self.detected_in_reference,
                "detected_at_s": list(self.detected_at_s),
                "residuals_mm": self.residuals_mm,
                "fre_rms_mm": self.fre_rms_mm,
                "fre_mean_mm": self.fre_mean_mm,
                "fle_rms_mm": self.fle_rms_mm,
            }
        )

    @classmethod
    def from_dict(
        cls, data: Mapping[str, Any], what: str = "landmark registration"
    ) -> LandmarkRegistrationResult:
        check_schema(data, "spacecal.landmark_registration", (1,), what)
        return cls(
            reference_from_phantom=as_transform(
                data.get("reference_from_phantom"), "reference_from_phantom", what
            ),
            detected_in_reference=as_array(
                data.get("landmarks_detected_in_reference_mm"),
                (None, 3),
                "landmarks_detected_in_reference_mm",
                what,
            ),
            detected_at_s=[float(t) for t in _finite(data.get("detected_at_s", []), "detected_at_s", what)],
            residuals_mm=_finite(data.get("residuals_mm"), "residuals_mm", what),
            fre_rms_mm=get_number(data, "fre_rms_mm", what),
            fre_mean_mm=get_number(data, "fre_mean_mm", what),
            fle_rms_mm=get_number(data, "fle_rms_mm", what),
        )


@dataclass(frozen=True)
class PivotResult:
    """Tip and pivot of a pivot calibration.

    Attributes
    ----------
    method : str
    tip_in_marker : numpy.ndarray, shape (3,)
        The tip in the marker frame, mm.
    pivot_in_tracker : numpy.ndarray, shape (3,)
        The pivot point in the tracker frame, mm.
    residuals_mm : numpy.ndarray, shape (N,)
        ``|tracker_from_marker_i @ tip - pivot|`` per frame (empty when read from a version-1
        file, which kept only their summary).
    summary : dict or None
        ``frames``, ``residual_rms_mm``, ``residual_mean_mm``, ``residual_max_mm`` of a
        version-1 file.
    tip_covariance_mm2 : numpy.ndarray, shape (3, 3), or None
        The tip's error covariance in the marker frame from the fit
        (:func:`spacecal.registration.pivot.tip_covariance`); None in files written before it.
    """

    method: str
    tip_in_marker: np.ndarray
    pivot_in_tracker: np.ndarray
    residuals_mm: np.ndarray
    summary: dict[str, float] | None = None
    tip_covariance_mm2: np.ndarray | None = None

    def __post_init__(self) -> None:
        what = "pivot"
        object.__setattr__(self, "tip_in_marker", as_array(self.tip_in_marker, (3,), "tip_in_marker", what))
        object.__setattr__(
            self, "pivot_in_tracker", as_array(self.pivot_in_tracker, (3,), "pivot_in_tracker", what)
        )
        object.__setattr__(self, "residuals_mm", _finite(self.residuals_mm, "residuals_mm", what))
        if not len(self.residuals_mm) and self.summary is None:
            raise InvalidInputError(f"{what}: no residuals")
        if self.tip_covariance_mm2 is not None:
            covariance = as_covariance(self.tip_covariance_mm2, 3, "tip_covariance_mm2", what)
            object.__setattr__(self, "tip_covariance_mm2", covariance)

    @property
    def frames(self) -> int:
        return int(self.summary["frames"]) if self.summary else len(self.residuals_mm)

    @property
    def rms_mm(self) -> float:
        """3-D RMS residual, mm."""
        if self.summary:
            return float(self.summary["residual_rms_mm"])
        return float(np.sqrt(np.mean(self.residuals_mm**2)))

    @property
    def rms_per_axis_mm(self) -> float:
        """Per-axis RMS, mm: scikit-surgerycalibration's ``residual`` (3-D RMS / sqrt(3))."""
        return float(self.rms_mm / np.sqrt(3.0))

    def to_dict(self) -> dict[str, Any]:
        mean = self.summary["residual_mean_mm"] if self.summary else float(self.residuals_mm.mean())
        largest = self.summary["residual_max_mm"] if self.summary else float(self.residuals_mm.max())
        return plain(
            {
                "schema": "spacecal.pivot",
                "schema_version": 2,
                "units": {"length": "mm"},
                "method": self.method,
                "tip_in_marker_mm": self.tip_in_marker,
                "pivot_in_tracker_mm": self.pivot_in_tracker,
                "frames": self.frames,
                "residual_rms_mm": self.rms_mm,
                "residual_rms_per_axis_mm": self.rms_per_axis_mm,
                "residual_mean_mm": mean,
                "residual_max_mm": largest,
                "residuals_mm": self.residuals_mm,
                **(
                    {} if self.tip_covariance_mm2 is None else {"tip_covariance_mm2": self.tip_covariance_mm2}
                ),
            }
        )

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], what: str = "pivot") -> PivotResult:
        """Read a pivot file, version 1 (summary only) or 2 (with every residual)."""
        version = check_schema(data, "spacecal.pivot", (1, 2), what)
        residuals = (
            _finite(data.get("residuals_mm", []), "residuals_mm", what) if version >= 2 else np.zeros(0)
        )
        summary = None
        if version == 1:
            summary = {
                key: get_number(data, key, what)
                for key in ("frames", "residual_rms_mm", "residual_mean_mm", "residual_max_mm")
            }
        return cls(
            method=get_str(data, "method", what, default="unknown"),
            tip_in_marker=as_array(data.get("tip_in_marker_mm"), (3,), "tip_in_marker_mm", what),
            pivot_in_tracker=as_array(data.get("pivot_in_tracker_mm"), (3,), "pivot_in_tracker_mm", what),
            residuals_mm=residuals,
            summary=summary,
            tip_covariance_mm2=None
            if data.get("tip_covariance_mm2") is None
            else as_array(data["tip_covariance_mm2"], (3, 3), "tip_covariance_mm2", what),
        )
