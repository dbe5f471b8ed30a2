"""The calibration result: the two transforms, how they were obtained, and how good they are.

Schema history of the calibration file (``schema: spacecal.calibration``):

* 1: the identified robot model rode in ``diagnostics["kinematic_model"]`` and the origin
  of the data in an untyped ``source`` object (``{"recording": path}``).
* 2: ``robot_model`` and ``provenance`` are typed fields.
* 3: an ``integrity`` object carries the sha256 of the canonical JSON of every other field
  (:mod:`spacecal.records.integrity`), so an edited file is detected; ``provenance`` names
  what the calibration belongs to: the recording's sha256 (and the raw tracker stream's), the
  marker's tool definition and its sha256, and the devices' serial numbers where known.
* 4: a ``needle_tip`` object: the needle tip a pivot calibration measured in the marker frame,
  with its error covariance and the pivot file it came from. Only a calibration with a tip is
  written as version 4, so a reader that knows no tip refuses it instead of aiming the TCP.

Within versions 3 and 4, ``provenance.source`` (a :class:`~spacecal.records.RecordingSource`:
the recording's files with their sha256, and the clock offset raw streams were paired at) and
``provenance.tracker_kind`` came later; a file without them is read from the loose
``provenance`` fields, ``diagnostics["time_offset_s"]`` and ``diagnostics["tracker_kind"]``
that files held before. Readers of earlier versions ignore the two keys and still find the
loose fields, which are written too.

Versions 1 and 2 are still read; they carry no hash, so they cannot be verified
(:attr:`CalibrationResult.integrity` says so).
"""

from __future__ import annotations

import dataclasses
import datetime
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from spacecal.core.errors import InvalidInputError
from spacecal.core.frames import transform_name
from spacecal.models.kinematics import MAX_JOINTS, RobotModel
from spacecal.records.assessment import ASSESSMENT_KEYS, Assessment, ExpectedError
from spacecal.records.fields import (
    ReadOnlyMapping,
    as_array,
    as_covariance,
    as_transform,
    check_schema,
    get_mapping,
    get_number,
    get_str,
    plain,
)
from spacecal.records.fit_evidence import FIT_EVIDENCE_KEYS, NoiseSummary, SweepFits
from spacecal.records.integrity import INTEGRITY_KEY, Integrity, integrity_entry, is_sha256
from spacecal.records.integrity import content_sha256 as hash_of_content
from spacecal.records.recording_source import RecordingSource
from spacecal.records.results import PivotResult
from spacecal.records.verdict import Verdict

#: The file's names of the two transforms, built from the frame table (``<to>_from_<from>``).
TRACKER_FROM_BASE = transform_name("tracker", "base")
TCP_FROM_MARKER = transform_name("tcp", "marker")

#: Larger than this (mm) is not a translation between a robot, a tracker and a marker.
MAX_TRANSLATION_MM = 1e5

CALIBRATION_SCHEMA = "spacecal.calibration"
CALIBRATION_SCHEMA_VERSION = 3
#: The version of a calibration that carries a needle tip.
NEEDLE_TIP_SCHEMA_VERSION = 4
#: Versions :meth:`CalibrationResult.from_dict` reads.
CALIBRATION_READABLE_VERSIONS = (1, 2, 3, 4)
#: The first version whose files carry a content hash.
FIRST_HASHED_VERSION = 3


def robot_model_to_dict(model: RobotModel) -> dict[str, Any]:
    """A robot model as plain JSON values (DH table in mm and rad, tool, limits, rate; the DH
    convention only when it is not the standard one, so files of standard-DH arms are as before)."""
    values = {
        "name": model.name,
        **model.dh_table(),
        "flange_from_tcp": model.flange_from_tcp.tolist(),
        "joint_lower_rad": model.joint_lower_rad.tolist(),
        "joint_upper_rad": model.joint_upper_rad.tolist(),
        "controller_hz": model.controller_hz,
    }
    if model.dh_convention != "standard":
        values["dh_convention"] = model.dh_convention
    return values


def robot_model_from_dict(data: Mapping[str, Any], what: str, base: RobotModel | None = None) -> RobotModel:
    """The inverse of :func:`robot_model_to_dict`; fields missing from ``data`` come from ``base``.

    Version-1 calibration files stored only the DH table and the name; their tool offset,
    limits and rate are taken from ``base`` (the nominal model) when given.
    """
    name = get_str(data, "name", what, default=base.name if base else "robot")
    values: dict[str, Any] = {"name": name}
    # the joint count is the DH table's (six on a UR arm); RobotModel checks the rest agree
    joints = len(data["a_mm"]) if isinstance(data.get("a_mm"), list) else (base.n_joints if base else 6)
    if not 1 <= joints <= MAX_JOINTS:
        raise InvalidInputError(f"{what}: robot_model.a_mm has {joints} joints; 1 to {MAX_JOINTS} are read")
    for key in ("a_mm", "d_mm", "alpha_rad", "theta_offset_rad", "joint_lower_rad", "joint_upper_rad"):
        if key in data:
            values[key] = as_array(data[key], (joints,), f"robot_model.{key}", what)
        elif base is not None:
            values[key] = getattr(base, key)
        elif key in ("a_mm", "d_mm", "alpha_rad"):
            raise InvalidInputError(f"{what}: robot_model lacks {key!r}")
    if "flange_from_tcp" in data:
        values["flange_from_tcp"] = as_transform(data["flange_from_tcp"], "robot_model.flange_from_tcp", what)
    elif base is not None:
        values["flange_from_tcp"] = base.flange_from_tcp
    if "controller_hz" in data:
        values["controller_hz"] = float(data["controller_hz"])
    elif base is not None:
        values["controller_hz"] = base.controller_hz
    if "dh_convention" in data:
        values["dh_convention"] = get_str(data, "dh_convention", what)
    elif base is not None:
        values["dh_convention"] = base.dh_convention
    return RobotModel(**values)


@dataclass(frozen=True)
class Provenance:
    """Where a result came from, so later steps need not guess.

    Attributes
    ----------
    source : RecordingSource or None
        The recording calibrated: its files (absolute paths) and their sha256 taken when
        calibrating, and how raw streams were paired (the clock offset and where it came from).
        ``recording``, ``tracker_stream``, ``recording_sha256`` and ``tracker_stream_sha256``
        read it.
    simulated : bool or None
        True for data from spacecal's simulator, False for real devices, None when unknown
        (e.g. an imported file).
    scenario : dict or None
        The simulation scenario the data came from (simulated data only).
    devices : dict
        Device identities where known: ``robot`` (``model``, ``url``, ``serial``) and
        ``tracker`` (``url``, ``name``, ``model``, ``serial``), as the recording's metadata
        states them.
    tool_definition : str or None
        Absolute path of the marker's tool definition (NDI ``.rom``) the recording names.
    tool_definition_sha256 : str or None
        Its sha256 when calibrating (None when the recording names none, or it was not there).
    tracker_kind : str or None
        What the tracker was taken to measure (``calibrate --tracker-kind``: ``auto``,
        ``spheres`` or ``pose``); None when not recorded.
    created_utc : str
        ISO time the result was made.
    software : str
        ``spacecal <version>``.
    """

    source: RecordingSource | None = None
    simulated: bool | None = None
    scenario: dict[str, Any] | None = None
    devices: dict[str, Any] = field(default_factory=dict)
    tool_definition: str | None = None
    tool_definition_sha256: str | None = None
    tracker_kind: str | None = None
    created_utc: str = field(
        default_factory=lambda: datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    )
    software: str = field(default_factory=lambda: f"spacecal {_version()}")

    @property
    def recording(self) -> str | None:
        """Absolute path of the recording calibrated (the robot stream of raw streams)."""
        return None if self.source is None else self.source.recording

    @property
    def tracker_stream(self) -> str | None:
        """Absolute path of the raw tracker stream, when the recording was two raw streams."""
        return None if self.source is None else self.source.tracker_stream

    @property
    def recording_sha256(self) -> str | None:
        return None if self.source is None else self.source.recording_sha256

    @property
    def tracker_stream_sha256(self) -> str | None:
        return None if self.source is None else self.source.tracker_stream_sha256

    def to_dict(self) -> dict[str, Any]:
        """The provenance object of the file; the loose ``recording``, ``tracker_stream`` and
        their ``*_sha256`` are written beside ``source`` for readers of earlier versions."""
        return plain(
            {
                "recording": self.recording,
                "tracker_stream": self.tracker_stream,
                "simulated": self.simulated,
                "scenario": self.scenario,
                "devices": self.devices,
                "recording_sha256": self.recording_sha256,
                "tracker_stream_sha256": self.tracker_stream_sha256,
                "tool_definition": self.tool_definition,
                "tool_definition_sha256": self.tool_definition_sha256,
                "created_utc": self.created_utc,
                "software": self.software,
                "source": None if self.source is None else self.source.to_dict(),
                "tracker_kind": self.tracker_kind,
            }
        )

    @classmethod
    def from_dict(
        cls, data: Mapping[str, Any], what: str, older_keys: Mapping[str, Any] | None = None
    ) -> Provenance:
        """Read a provenance object; one without ``source`` (files of earlier versions) has its
        source built from the loose fields and the clock offset in ``older_keys`` (the file's
        diagnostics object, ``time_offset_s``), and its tracker kind from there too."""
        older_keys = older_keys or {}
        simulated = data.get("simulated")
        tool_definition = data.get("tool_definition")
        for key in ("recording", "tracker_stream", "tool_definition"):
            value = data.get(key)
            if value is not None and not isinstance(value, str):
                raise InvalidInputError(f"{what}: provenance {key!r} must be a path string")
        for key in ("recording_sha256", "tracker_stream_sha256", "tool_definition_sha256"):
            value = data.get(key)
            if value is not None and not is_sha256(value):
                raise InvalidInputError(
                    f"{what}: provenance {key!r} must be a sha256 (64 hex digits) or null"
                )
        if simulated is not None and not isinstance(simulated, bool):
            raise InvalidInputError(f"{what}: provenance 'simulated' must be true, false or null")
        scenario = data.get("scenario")
        if scenario is not None and not isinstance(scenario, Mapping):
            raise InvalidInputError(f"{what}: provenance 'scenario' must be an object")
        source: RecordingSource | None = None
        if data.get("source") is not None:
            source = RecordingSource.from_dict(data["source"], f"{what}: provenance source")
        else:
            source = RecordingSource.from_old_provenance(data, older_keys, what)
        kind = data["tracker_kind"] if "tracker_kind" in data else older_keys.get("tracker_kind")
        if kind is not None and not isinstance(kind, str):
            raise InvalidInputError(f"{what}: provenance 'tracker_kind' must be a string or null")
        return cls(
            source=source,
            simulated=simulated,
            scenario=None if scenario is None else dict(scenario),
            devices=get_mapping(data, "devices", what),
            tool_definition=tool_definition,
            tool_definition_sha256=data.get("tool_definition_sha256"),
            tracker_kind=kind,
            created_utc=get_str(data, "created_utc", what, default=""),
            software=get_str(data, "software", what, default=""),
        )


def _version() -> str:
    from spacecal import __version__

    return __version__


@dataclass(frozen=True)
class NeedleTip:
    """The needle tip as a pivot calibration measured it: a point fixed to the marker.

    The last link's kinematic errors move the tip in the flange frame, where no marker on the
    tool sees them (``tcp_from_marker`` absorbs them, and the controller's TCP stays off by
    them); a tip measured in the marker frame and aimed through ``tcp_from_marker`` removes
    them (the docs' systematic-error tables measure it).

    Attributes
    ----------
    tip_in_marker : numpy.ndarray, shape (3,)
        The tip in the marker frame, mm (``spacecal pivot``).
    covariance_mm2 : numpy.ndarray, shape (3, 3)
        The tip's error covariance in the marker frame, mm^2.
    covariance_basis : str
        Where the covariance comes from (the pivot fit's, or its residual RMS when the pivot
        file has none).
    pivot_rms_mm : float
        The pivot's 3-D RMS residual, mm.
    frames : int
        Frames of the pivot.
    source : str or None
        The pivot file.
    source_sha256 : str or None
        Its sha256.
    """

    tip_in_marker: np.ndarray
    covariance_mm2: np.ndarray
    covariance_basis: str
    pivot_rms_mm: float
    frames: int
    source: str | None = None
    source_sha256: str | None = None

    def __post_init__(self) -> None:
        what = "needle tip"
        tip = as_array(self.tip_in_marker, (3,), "tip_in_marker_mm", what)
        if np.max(np.abs(tip)) > MAX_TRANSLATION_MM:
            raise InvalidInputError(f"{what}: the tip is {np.max(np.abs(tip)):.3g} mm from the marker")
        covariance = as_covariance(self.covariance_mm2, 3, "covariance_mm2", what)
        if not (np.isfinite(self.pivot_rms_mm) and self.pivot_rms_mm >= 0) or int(self.frames) < 1:
            raise InvalidInputError(f"{what}: pivot_rms_mm and frames must be a distance and a count")
        object.__setattr__(self, "tip_in_marker", tip)
        object.__setattr__(self, "covariance_mm2", covariance)

    @classmethod
    def from_pivot(
        cls, pivot: PivotResult, source: str | None = None, source_sha256: str | None = None
    ) -> NeedleTip:
        """The tip of a pivot calibration, its error taken as the residual's per-axis RMS in
        each axis.

        The fit's own covariance (``pivot.tip_covariance_mm2``) sees only the tracker's scatter;
        the tracker's smooth bias over the pivot's cone moves the tip as much as it moves the
        residual. Measured on simulated pivots (200 frames, 25 deg cone, ``systematic-nominal``'s
        tracker with a bias of 0.2 mm RMS, 10 seeds): tips 0.21 mm off on average (largest 0.40)
        where the fit's s.d. says 0.06 mm per axis and the residual 0.21 mm per axis.
        """
        covariance = np.eye(3) * pivot.rms_per_axis_mm**2
        basis = "the pivot's residual RMS per axis (it holds the tracker's bias over the cone)"
        return cls(pivot.tip_in_marker, covariance, basis, pivot.rms_mm, pivot.frames, source, source_sha256)

    @property
    def sd_mm(self) -> float:
        """RMS over the three axes of the tip's standard deviation, mm."""
        return float(np.sqrt(np.trace(self.covariance_mm2) / 3.0))

    def to_dict(self) -> dict[str, Any]:
        return plain(
            {
                "tip_in_marker_mm": self.tip_in_marker,
                "covariance_mm2": self.covariance_mm2,
                "covariance_basis": self.covariance_basis,
                "pivot_rms_mm": self.pivot_rms_mm,
                "frames": int(self.frames),
                "source": self.source,
                "source_sha256": self.source_sha256,
            }
        )

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], what: str = "needle tip") -> NeedleTip:
        source, digest = data.get("source"), data.get("source_sha256")
        if source is not None and not isinstance(source, str):
            raise InvalidInputError(f"{what}: source must be a path string")
        if digest is not None and not is_sha256(digest):
            raise InvalidInputError(f"{what}: source_sha256 must be a sha256 (64 hex digits)")
        return cls(
            tip_in_marker=as_array(data.get("tip_in_marker_mm"), (3,), "tip_in_marker_mm", what),
            covariance_mm2=as_array(data.get("covariance_mm2"), (3, 3), "covariance_mm2", what),
            covariance_basis=get_str(data, "covariance_basis", what, default=""),
            pivot_rms_mm=get_number(data, "pivot_rms_mm", what),
            frames=int(get_number(data, "frames", what)),
            source=source,
            source_sha256=digest,
        )


@dataclass(frozen=True)
class CalibrationResult:
    """The outcome of a calibration.

    Attributes
    ----------
    method : str
        Registry name of the estimator.
    tracker_from_base : numpy.ndarray, shape (4, 4)
        Maps base coordinates into the tracker frame, mm. What navigation needs.
    tcp_from_marker : numpy.ndarray, shape (4, 4)
        Pose of the marker on the tool, mm.
    sample_counts : dict
        ``{"total", "used", "rejected", "per_segment": {...}}`` (see
        :func:`spacecal.estimators.methods.samples.sample_counts`).
    diagnostics : dict
        Method-specific quality figures (see each estimator); the assessment is not among
        them (:attr:`assessment`).
    provenance : Provenance
        Where the data came from.
    covariance : dict, optional
        ``{"parameters": [12 names], "matrix": 12x12}``: covariance of the perturbation
        parameters of both transforms (see :mod:`spacecal.estimators.methods.ml`), mm and rad.
    predicted_tre_mm : dict, optional
        Predicted RMS target registration error at the surgical site, over a cube around
        it, and at user targets.
    robot_model : RobotModel, optional
        The robot's kinematic model identified with the calibration (``kinematic``); IK
        for this calibration must use it.
    schema_version : int
        The version of the file it was read from (the current one for a new result).
    integrity : Integrity or None
        How the file it was read from stands against its content hash; None for a result not
        read from a file. Whether an edited file may be used is the caller's decision.
    needle_tip : NeedleTip or None
        The needle tip a pivot calibration measured; IK aims it (:attr:`tcp_from_needle`)
        instead of the controller's TCP.
    assessment : ~spacecal.records.assessment.Assessment or None
        The expected error, residuals, thresholds and verdict
        (:mod:`spacecal.estimators.assessment` builds it); None for a method run without its
        uncertainty.
    sweep_fits : SweepFits or None
        The paper method's sphere and line fits (``paper``), None for the others.
    noise : NoiseSummary or None
        The tracker noise a likelihood fit was weighted with.
    """

    method: str
    tracker_from_base: np.ndarray
    tcp_from_marker: np.ndarray
    sample_counts: dict[str, Any]
    diagnostics: dict[str, Any]
    provenance: Provenance = field(default_factory=Provenance)
    covariance: dict[str, Any] | None = None
    predicted_tre_mm: dict[str, Any] | None = None
    robot_model: RobotModel | None = None
    schema_version: int = CALIBRATION_SCHEMA_VERSION
    integrity: Integrity | None = field(default=None, compare=False)
    needle_tip: NeedleTip | None = None
    assessment: Assessment | None = None
    sweep_fits: SweepFits | None = None
    noise: NoiseSummary | None = None

    def __post_init__(self) -> None:
        what = f"calibration ({self.method})"
        object.__setattr__(
            self, "tracker_from_base", as_transform(self.tracker_from_base, "tracker_from_base", what)
        )
        object.__setattr__(
            self, "tcp_from_marker", as_transform(self.tcp_from_marker, "tcp_from_marker", what)
        )
        for name in ("tracker_from_base", "tcp_from_marker"):
            translation = getattr(self, name)[:3, 3]
            if np.max(np.abs(translation)) > MAX_TRANSLATION_MM:
                raise InvalidInputError(
                    f"{what}: {name} translation {np.max(np.abs(translation)):.3g} mm is not a distance "
                    f"in the room (at most {MAX_TRANSLATION_MM:g} mm)"
                )
        if not isinstance(self.sample_counts, dict) or not isinstance(self.diagnostics, Mapping):
            raise InvalidInputError(f"{what}: sample_counts and diagnostics must be objects")
        # built once: what a method found is not changed afterwards (its keys; see ReadOnlyMapping)
        object.__setattr__(self, "diagnostics", ReadOnlyMapping(self.diagnostics))
        misplaced = sorted(set(self.diagnostics) & {*ASSESSMENT_KEYS, *FIT_EVIDENCE_KEYS})
        if misplaced:
            # one place for each typed field: a second copy among the diagnostics could disagree
            raise InvalidInputError(
                f"{what}: {', '.join(misplaced)} are typed fields of the calibration, not diagnostics"
            )
        if self.assessment is not None and not isinstance(self.assessment, Assessment):
            raise InvalidInputError(f"{what}: assessment must be an Assessment")

    @property
    def verdict(self) -> Verdict | None:
        """The verdict on this calibration (grade, expected error, reasons), None when the
        method gave none; older files' sentences are read too."""
        return None if self.assessment is None else self.assessment.verdict

    @property
    def expected_error(self) -> ExpectedError | None:
        """The error to expect at a target near the site, None when none was stated."""
        return None if self.assessment is None else self.assessment.expected_error

    @property
    def tcp_from_needle(self) -> np.ndarray | None:
        """Where IK puts the needle tip, (4, 4) in the TCP frame, mm: the measured tip carried
        by ``tcp_from_marker`` (axes those of the TCP); None without a measured tip (the
        controller's TCP is the tip)."""
        if self.needle_tip is None:
            return None
        needle = np.eye(4)
        needle[:3, 3] = (
            self.tcp_from_marker[:3, :3] @ self.needle_tip.tip_in_marker + self.tcp_from_marker[:3, 3]
        )
        return needle

    @property
    def content_sha256(self) -> str:
        """The content hash that identifies this calibration (a check history binds to it): of
        the file as read, or, for a result not read from a file, of what writing it would give."""
        if self.integrity is not None:
            return self.integrity.content_sha256
        return hash_of_content(self.to_dict())

    def robot_model_for_ik(self, nominal: RobotModel) -> RobotModel:
        """The model to solve IK with: ``nominal`` with the identified DH parameters, if any.

        The tool offset, joint limits and controller rate stay those of ``nominal`` (the
        robot as configured now); only the kinematic parameters come from the calibration.
        """
        if self.robot_model is None:
            return nominal
        identified = self.robot_model
        return dataclasses.replace(
            nominal,
            a_mm=identified.a_mm,
            d_mm=identified.d_mm,
            alpha_rad=identified.alpha_rad,
            theta_offset_rad=identified.theta_offset_rad,
        )

    def replace(self, **changes: Any) -> CalibrationResult:
        """A copy with some fields changed (the record itself is immutable); the copy was not
        read from a file, so it has no ``integrity`` unless given."""
        changes.setdefault("integrity", None)
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        """The calibration file's content (the current schema), with its content hash."""
        content = plain(
            {
                "schema": CALIBRATION_SCHEMA,
                "schema_version": CALIBRATION_SCHEMA_VERSION
                if self.needle_tip is None
                else NEEDLE_TIP_SCHEMA_VERSION,
                "spacecal_version": _version(),
                "created_utc": self.provenance.created_utc,
                "units": {"length": "mm", "angle": "rad"},
                "method": self.method,
                TRACKER_FROM_BASE: self.tracker_from_base,
                TCP_FROM_MARKER: self.tcp_from_marker,
                "sample_counts": self.sample_counts,
                "diagnostics": {
                    **self.diagnostics,
                    **({} if self.assessment is None else self.assessment.to_diagnostics()),
                    **({} if self.sweep_fits is None else self.sweep_fits.to_diagnostics()),
                    **({} if self.noise is None else {"noise": self.noise.to_dict()}),
                },
                "provenance": self.provenance.to_dict(),
                "covariance": self.covariance,
                "predicted_tre_mm": self.predicted_tre_mm,
                "robot_model": None if self.robot_model is None else robot_model_to_dict(self.robot_model),
                **({} if self.needle_tip is None else {"needle_tip": self.needle_tip.to_dict()}),
            }
        )
        return {**content, INTEGRITY_KEY: integrity_entry(content)}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], what: str = "calibration") -> CalibrationResult:
        """Read a calibration file's content, version 1, 2 or 3, and hash it
        (:attr:`integrity`; an edited file is read, not refused: the caller decides)."""
        version = check_schema(data, CALIBRATION_SCHEMA, CALIBRATION_READABLE_VERSIONS, what)
        if "schema_version" not in data:
            raise InvalidInputError(f"{what}: missing 'schema_version' (not a spacecal calibration file?)")
        # the assessment rides in the file's diagnostics object, as every version wrote it
        assessment, stored = Assessment.from_diagnostics(get_mapping(data, "diagnostics", what), what)
        sweep_fits = SweepFits.from_diagnostics(stored, what)
        noise = (
            None if stored.get("noise") is None else NoiseSummary.from_dict(stored["noise"], f"{what}: noise")
        )
        stored = {k: v for k, v in stored.items() if k not in FIT_EVIDENCE_KEYS}
        covariance = data.get("covariance")
        if covariance is not None and not isinstance(covariance, Mapping):
            raise InvalidInputError(f"{what}: 'covariance' must be an object")
        predicted = data.get("predicted_tre_mm")
        if predicted is not None:
            predicted = get_mapping(data, "predicted_tre_mm", what)
            for key in ("site", "cube_rms"):
                if key in predicted and (
                    isinstance(predicted[key], bool) or not isinstance(predicted[key], (int, float))
                ):
                    raise InvalidInputError(f"{what}: predicted_tre_mm.{key} must be a number")
        for key in (TRACKER_FROM_BASE, TCP_FROM_MARKER):
            if key not in data:
                raise InvalidInputError(f"{what}: missing {key!r}")
        units = get_mapping(data, "units", what)
        if units.get("length", "mm") != "mm" or units.get("angle", "rad") != "rad":
            raise InvalidInputError(
                f"{what}: units {units!r}; a spacecal calibration is in mm and rad (convert it first)"
            )
        if version == 1:
            # v1: the robot model in diagnostics, the recording path in "source"
            model_data = stored.get("kinematic_model")
            recording = _optional_path(get_mapping(data, "source", what).get("recording"), what)
            provenance = Provenance(
                source=None if recording is None else RecordingSource.paired_csv(recording),
                tracker_kind=_optional_kind(stored.get("tracker_kind")),
                created_utc=str(data.get("created_utc", "")),
                software=f"spacecal {data.get('spacecal_version', '')}".strip(),
            )
        else:
            model_data = data.get("robot_model")
            # older files kept the clock offset and the tracker kind among their diagnostics
            provenance = Provenance.from_dict(get_mapping(data, "provenance", what), what, stored)
        robot_model = None
        if model_data is not None:
            if not isinstance(model_data, Mapping):
                raise InvalidInputError(f"{what}: robot_model must be an object")
            from spacecal.models.robot_kinds import is_robot_kind, robot_kind

            name = model_data.get("name")
            base = robot_kind(name).model() if is_robot_kind(name) else None
            robot_model = robot_model_from_dict(model_data, what, base)
        needle_tip = None
        if version >= NEEDLE_TIP_SCHEMA_VERSION and data.get("needle_tip") is not None:
            needle_tip = NeedleTip.from_dict(get_mapping(data, "needle_tip", what), f"{what}: needle_tip")
        return cls(
            method=get_str(data, "method", what, default="unknown"),
            tracker_from_base=as_transform(data[TRACKER_FROM_BASE], TRACKER_FROM_BASE, what),
            tcp_from_marker=as_transform(data[TCP_FROM_MARKER], TCP_FROM_MARKER, what),
            sample_counts=get_mapping(data, "sample_counts", what),
            diagnostics=stored,
            provenance=provenance,
            covariance=None if covariance is None else dict(covariance),
            predicted_tre_mm=predicted,
            robot_model=robot_model,
            schema_version=version,
            integrity=Integrity.of(data, required=version >= FIRST_HASHED_VERSION),
            needle_tip=needle_tip,
            assessment=assessment,
            sweep_fits=sweep_fits,
            noise=noise,
        )


def _optional_path(value: Any, what: str) -> str | None:
    if value is None:
        return None
    if not isinstance(value, str):
        raise InvalidInputError(f"{what}: source 'recording' must be a path string")
    return value


def _optional_kind(value: Any) -> str | None:
    return value if isinstance(value, str) else None
