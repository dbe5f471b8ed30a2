"""JSON files for calibration and verification results.

A calibration file holds at least ``tracker_from_base`` and ``tcp_from_marker`` (4x4 lists,
mm), ``method``, ``sample_counts``, ``diagnostics`` and ``schema_version``.
"""

from __future__ import annotations

import datetime
import json
from pathlib import Path

import numpy as np

from spacecal import __version__
from spacecal.core.errors import InvalidInputError
from spacecal.geometry.transforms import is_rigid_transform
from spacecal.records import CALIBRATION_SCHEMA_VERSION, CalibrationResult


def _plain(value):
    """Turn numpy values inside nested containers into JSON-ready Python values."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    return value


def write_json(data: dict, path: str | Path) -> Path:
    """Write a dict (numpy values allowed) as indented JSON; returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(_plain(data), indent=2) + "\n")
    return path


def read_json_object(path: str | Path, what: str) -> dict:
    """Read a JSON file that must hold an object; one-line errors name the file and ``what`` it is."""
    path = Path(path)
    if not path.is_file():
        raise InvalidInputError(f"{path}: no such {what} file")
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise InvalidInputError(f"{path}: not valid JSON: {exc.msg} (line {exc.lineno})") from None
    if not isinstance(data, dict):
        raise InvalidInputError(f"{path}: a {what} file holds a JSON object")
    return data


def calibration_to_dict(result: CalibrationResult) -> dict:
    return {
        "schema": "spacecal.calibration",
        "schema_version": result.schema_version,
        "spacecal_version": __version__,
        "created_utc": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "units": {"length": "mm", "angle": "rad"},
        "method": result.method,
        "tracker_from_base": result.tracker_from_base,
        "tcp_from_marker": result.tcp_from_marker,
        "sample_counts": result.sample_counts,
        "diagnostics": result.diagnostics,
        "source": result.source,
        "covariance": result.covariance,
        "predicted_tre_mm": result.predicted_tre_mm,
    }


def write_calibration(result: CalibrationResult, path: str | Path) -> Path:
    """Write a calibration result file."""
    return write_json(calibration_to_dict(result), path)


def _matrix(data: dict, key: str, path: Path) -> np.ndarray:
    if key not in data:
        raise InvalidInputError(f"{path}: missing {key!r}")
    try:
        matrix = np.array(data[key], dtype=float)
    except (TypeError, ValueError):
        raise InvalidInputError(f"{path}: {key!r} is not a 4x4 list of numbers") from None
    if matrix.shape != (4, 4) or not is_rigid_transform(matrix, atol=1e-6):
        raise InvalidInputError(f"{path}: {key!r} is not a 4x4 rigid transform")
    return matrix


def read_calibration(path: str | Path) -> CalibrationResult:
    """Read and validate a calibration result file."""
    path = Path(path)
    data = read_json_object(path, "calibration")
    version = data.get("schema_version")
    if version != CALIBRATION_SCHEMA_VERSION:
        raise InvalidInputError(
            f"{path}: schema_version {version!r} is not supported (this spacecal reads {CALIBRATION_SCHEMA_VERSION})"
        )
    return CalibrationResult(
        method=str(data.get("method", "unknown")),
        tracker_from_base=_matrix(data, "tracker_from_base", path),
        tcp_from_marker=_matrix(data, "tcp_from_marker", path),
        sample_counts=data.get("sample_counts", {}),
        diagnostics=data.get("diagnostics", {}),
        source=data.get("source", {}),
        covariance=data.get("covariance"),
        predicted_tre_mm=data.get("predicted_tre_mm"),
        schema_version=version,
    )
