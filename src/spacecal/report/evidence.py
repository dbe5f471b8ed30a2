"""The numbers behind the report's figures, prepared once for both renderings (interactive
plotly in the HTML page, matplotlib PNGs): sweeps and fits, uncertainty split by unit, the
check history over time."""

from __future__ import annotations

import datetime
from dataclasses import dataclass

import numpy as np

from spacecal.records import CalibrationResult, CheckResult, Recording


@dataclass
class Sweep:
    """One labelled segment of a recording, with its fit where the method made one.

    Attributes
    ----------
    label : str
    marker_in_tracker : numpy.ndarray, shape (N, 3)
        Marker origin of the visible samples, tracker frame, mm.
    line_in_tracker : numpy.ndarray, shape (2, 3) or None
        End points of the fitted line (translation sweeps), mm.
    """

    label: str
    marker_in_tracker: np.ndarray
    line_in_tracker: np.ndarray | None = None


def sweeps(recording: Recording, calibration: CalibrationResult) -> list[Sweep]:
    """The visible marker positions per segment and, for translation sweeps, the fitted line
    (the method's own direction when it stored one, else the principal direction)."""
    found = []
    lines = {} if calibration.sweep_fits is None else calibration.sweep_fits.lines
    for label in dict.fromkeys(recording.segment.tolist()):
        rows = (recording.segment == label) & recording.visible
        points = recording.tracker_from_marker_stack[rows, :3, 3]
        if len(points) == 0:
            continue
        line = None
        if str(label).startswith("lin_") and len(points) > 1:
            fitted = lines.get(str(label))
            direction = np.asarray(
                np.linalg.svd(points - points.mean(0))[2][0]
                if fitted is None
                else fitted.direction_in_tracker,
                dtype=float,
            )
            along = (points - points.mean(0)) @ direction
            line = points.mean(0) + np.outer([along.min(), along.max()], direction)
        found.append(Sweep(str(label), points, line))
    return found


def fitted_sphere(calibration: CalibrationResult) -> tuple[np.ndarray, float] | None:
    """Centre (3,) in the tracker frame and radius, mm, of the paper method's sphere fit."""
    sphere = None if calibration.sweep_fits is None else calibration.sweep_fits.sphere
    if sphere is None:
        return None
    return np.asarray(sphere.centre_in_tracker_mm, dtype=float), sphere.radius_mm


@dataclass
class Uncertainty:
    """Standard deviations of the calibration's parameters, split by unit.

    Attributes
    ----------
    axes : list of str
        ``x``, ``y``, ``z``.
    translation_sd_mm, rotation_sd_deg : dict of str to numpy.ndarray, shape (3,)
        Per transform name (``tracker_from_base``, ``tcp_from_marker``).
    """

    axes: list[str]
    translation_sd_mm: dict[str, np.ndarray]
    rotation_sd_deg: dict[str, np.ndarray]


def uncertainty(calibration: CalibrationResult) -> Uncertainty | None:
    """The covariance's standard deviations: translations in mm, rotations in degrees."""
    covariance = calibration.covariance or {}
    names, matrix = covariance.get("parameters"), covariance.get("matrix")
    if not names or matrix is None:
        return None
    sd = np.sqrt(np.clip(np.diag(np.asarray(matrix, dtype=float)), 0.0, None))
    translation: dict[str, np.ndarray] = {}
    rotation: dict[str, np.ndarray] = {}
    axes = ["x", "y", "z"]
    for name, value in zip(names, sd):
        transform, _, parameter = str(name).rpartition(".")
        kind, _, rest = parameter.partition("_")
        axis = rest.split("_")[0]
        if axis not in axes:
            continue
        if kind == "v" and parameter.endswith("_mm"):
            translation.setdefault(transform, np.full(3, np.nan))[axes.index(axis)] = value
        elif kind == "w" and parameter.endswith("_rad"):
            rotation.setdefault(transform, np.full(3, np.nan))[axes.index(axis)] = np.degrees(value)
    if not translation and not rotation:
        return None
    return Uncertainty(axes, translation, rotation)


@dataclass
class CheckSeries:
    """The check history as points over time.

    Attributes
    ----------
    when : list of datetime.datetime or str
        Check times (UTC); the text as written when it is not an ISO time.
    worst_tcp_mm, worst_rotation_deg : numpy.ndarray, shape (C,)
    passed : numpy.ndarray of bool, shape (C,)
    threshold_mm, threshold_deg : float
        Of the newest check.
    """

    when: list
    worst_tcp_mm: np.ndarray
    worst_rotation_deg: np.ndarray
    passed: np.ndarray
    threshold_mm: float
    threshold_deg: float

    @property
    def dated(self) -> bool:
        return all(isinstance(t, datetime.datetime) for t in self.when)


def check_series(history: list[CheckResult]) -> CheckSeries:
    when: list = []
    for k, entry in enumerate(history):
        try:
            moment = datetime.datetime.fromisoformat(entry.checked_utc.replace("Z", "+00:00"))
            if moment.tzinfo is not None:
                moment = moment.astimezone(datetime.timezone.utc).replace(tzinfo=None)
            when.append(moment)
        except ValueError:
            when.append(entry.checked_utc or f"check {k + 1}")
    if not all(isinstance(t, datetime.datetime) for t in when):
        when = [entry.checked_utc or f"check {k + 1}" for k, entry in enumerate(history)]
    return CheckSeries(
        when,
        np.array([float(np.max(e.tcp_error_mm)) for e in history]),
        np.array([float(np.max(e.rotation_error_deg)) for e in history]),
        np.array([e.passed for e in history]),
        history[-1].threshold_mm,
        history[-1].threshold_deg,
    )


def tick_format(values) -> str:
    """A d3 number format with the decimals the data's tick spacing needs (0.0089 -> 0.009,
    not 8.9e-3 or 0.0089000), for axes starting at zero."""
    finite = np.abs(np.asarray(values, dtype=float))
    finite = finite[np.isfinite(finite)]
    top = float(finite.max()) if finite.size else 1.0
    if top <= 0:
        return ".1f"
    decimals = max(0, int(-np.floor(np.log10(top / 5.0))))
    return f".{decimals}f" if decimals <= 5 else ".1e"
