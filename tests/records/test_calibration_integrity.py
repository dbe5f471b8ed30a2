"""The calibration file's content hash: it survives a read/write round trip and any
re-formatting, and any edit of any field shows; older versions read as unverifiable."""

import json

import numpy as np
import pytest

from spacecal.core.errors import InvalidInputError
from spacecal.geometry.transforms import axis_angle_transform, make_transform
from spacecal.io.results_json import read_calibration, write_calibration
from spacecal.models.robot_kinds import robot_kind
from spacecal.records import CalibrationResult, Provenance, RecordingSource
from spacecal.records.assessment import Assessment, ExpectedError
from spacecal.records.calibration import CALIBRATION_READABLE_VERSIONS, CALIBRATION_SCHEMA_VERSION
from spacecal.records.integrity import canonical_json, content_sha256

#: Floats whose shortest text is awkward: they must hash the same after a trip through the file.
AWKWARD_FLOATS = [0.1 + 0.2, 1e16, 1e-300, 5e-324, -0.0, 1 / 3, 123456789.12345678, 2.0**53 + 1]


def a_calibration(**changes):
    rng = np.random.default_rng(3)
    tracker_from_base = axis_angle_transform(rng.normal(size=3), 0.7) @ make_transform(
        np.eye(3), rng.normal(size=3) * 900
    )
    values = dict(
        method="ml",
        tracker_from_base=tracker_from_base,
        tcp_from_marker=make_transform(np.eye(3), [60.0, 0.0, -150.0]),
        sample_counts={"total": 10, "used": 9, "rejected": 1, "per_segment": {"rot_x": 9}},
        assessment=Assessment(expected_error=ExpectedError(0.44, 0.08)),
        diagnostics={
            "awkward": AWKWARD_FLOATS,
            "rows": np.arange(5),
            "nested": {"deeper": {"value": float(rng.normal())}},
        },
        provenance=Provenance(
            source=RecordingSource.paired_csv("/data/rec.csv", "a" * 64),
            simulated=False,
            devices={"robot": {"model": "UR10", "url": "ur://10.0.0.2", "serial": "2019301234"}},
            tool_definition="/data/8700339.rom",
            tool_definition_sha256="b" * 64,
            # fixed, so two results made a second apart hash the same
            created_utc="2026-01-02T03:04:05+00:00",
        ),
        covariance={"parameters": ["p"] * 12, "matrix": np.eye(12) * 1e-4},
        predicted_tre_mm={"site": 0.02, "cube_rms": 0.03},
        robot_model=robot_kind("UR10").model(),
    )
    values.update(changes)
    return CalibrationResult(**values)


@pytest.fixture
def written(tmp_path):
    return write_calibration(a_calibration(), tmp_path / "cal.json")


def test_the_hash_survives_a_read_write_round_trip(written, tmp_path):
    data = json.loads(written.read_text())
    assert data["schema_version"] == CALIBRATION_SCHEMA_VERSION == 3
    assert data["integrity"]["algorithm"] == "sha256"
    assert data["integrity"]["content_sha256"] == content_sha256(data)
    read = read_calibration(written)
    assert read.integrity.verified and not read.integrity.edited and read.schema_version == 3
    assert read.diagnostics["awkward"] == AWKWARD_FLOATS  # bit for bit
    assert read.provenance.tool_definition_sha256 == "b" * 64
    assert read.provenance.devices["robot"]["serial"] == "2019301234"
    again = write_calibration(read, tmp_path / "again.json")
    assert json.loads(again.read_text()) == data  # nothing changed, so the same hash
    assert read_calibration(again).integrity.verified
    assert read.content_sha256 == data["integrity"]["content_sha256"] == a_calibration().content_sha256


def test_formatting_and_key_order_are_not_edits(written):
    data = json.loads(written.read_text())
    written.write_text(json.dumps(dict(reversed(list(data.items()))), indent=None, separators=(",", ":")))
    assert read_calibration(written).integrity.verified
    written.write_text(json.dumps(data, indent=7, sort_keys=True))
    assert read_calibration(written).integrity.verified


@pytest.mark.parametrize("seed", range(20))
def test_any_float_hashes_the_same_after_a_trip_through_the_file(tmp_path, seed):
    rng = np.random.default_rng(seed)
    values = (rng.normal(size=50) * 10.0 ** rng.integers(-300, 300, size=50)).tolist()
    path = write_calibration(a_calibration(diagnostics={"values": values}), tmp_path / "c.json")
    assert read_calibration(path).integrity.verified
    assert canonical_json({"v": values}) == canonical_json(json.loads(json.dumps({"v": values})))


def _every_top_level_edit():
    """One edit per top-level key of the file (and a few nested ones), each still a valid file."""
    rotate = axis_angle_transform([0, 0, 1], np.radians(0.5))
    edits = {
        "schema": None,  # a file of another schema is refused outright, not an edit
        "schema_version": lambda d: d.update(schema_version=2),  # the hash still vouches for it
        "spacecal_version": lambda d: d.update(spacecal_version="0.0.9"),
        "created_utc": lambda d: d.update(created_utc="2020-01-01T00:00:00+00:00"),
        "units": lambda d: d["units"].update(time="s"),
        "method": lambda d: d.update(method="paper"),
        "tracker_from_base": lambda d: d["tracker_from_base"][0].__setitem__(
            3, d["tracker_from_base"][0][3] + 2
        ),
        "tcp_from_marker": lambda d: d.update(
            tcp_from_marker=(rotate @ np.array(d["tcp_from_marker"])).tolist()
        ),
        "sample_counts": lambda d: d["sample_counts"].update(used=10),
        "diagnostics": lambda d: d["diagnostics"]["expected_error"].update(position_mm=0.1),
        "provenance": lambda d: d["provenance"].update(recording="/elsewhere/rec.csv"),
        "covariance": lambda d: d.update(covariance=None),
        "predicted_tre_mm": lambda d: d["predicted_tre_mm"].update(site=0.001),
        "robot_model": lambda d: d["robot_model"]["d_mm"].__setitem__(0, d["robot_model"]["d_mm"][0] + 0.1),
        "integrity": lambda d: d["integrity"].update(content_sha256="c" * 64),
    }
    return edits


TOP_LEVEL_EDITS = {k: v for k, v in _every_top_level_edit().items() if v is not None}
NESTED_EDITS = {
    "tracker_from_base by 2 mm": lambda d: d["tracker_from_base"][2].__setitem__(
        3, d["tracker_from_base"][2][3] - 2
    ),
    "tracker_from_base by 0.5 deg": lambda d: d.update(
        tracker_from_base=(
            axis_angle_transform([1, 0, 0], np.radians(0.5)) @ np.array(d["tracker_from_base"])
        ).tolist()
    ),
    "a device serial": lambda d: d["provenance"]["devices"]["robot"].update(serial="2019309999"),
    "the recording's sha256": lambda d: d["provenance"].update(recording_sha256="d" * 64),
    "a deeply nested number": lambda d: d["diagnostics"]["nested"]["deeper"].update(value=0.0),
    "a float's last digit": lambda d: d["diagnostics"]["awkward"].__setitem__(0, 0.3),
    "a new top-level key": lambda d: d.update(note="approved by me"),
    "a key removed": lambda d: d.pop("predicted_tre_mm"),
    "the hash removed": lambda d: d.pop("integrity"),
    "the hash mangled": lambda d: d.update(integrity={"algorithm": "md5", "content_sha256": 5}),
}


def test_every_top_level_key_is_covered():
    data = a_calibration().to_dict()
    assert set(_every_top_level_edit()) == set(data)


@pytest.mark.parametrize(
    "edit", {**TOP_LEVEL_EDITS, **NESTED_EDITS}.values(), ids=[*TOP_LEVEL_EDITS, *NESTED_EDITS]
)
def test_any_edit_shows(written, edit):
    data = json.loads(written.read_text())
    edit(data)
    written.write_text(json.dumps(data, indent=2))
    read = read_calibration(written)  # read (the app decides whether to use it)
    assert read.integrity.edited and not read.integrity.verified


def test_older_versions_read_as_unverifiable(written):
    data = json.loads(written.read_text())
    version_2 = {k: v for k, v in data.items() if k != "integrity"}
    version_2["schema_version"] = 2
    written.write_text(json.dumps(version_2))
    read = read_calibration(written)
    assert read.schema_version == 2 and read.integrity.unverifiable and not read.integrity.edited
    # a version 2 file carrying a hash vouches for its content like any other
    version_2["integrity"] = data["integrity"]
    written.write_text(json.dumps(version_2))
    assert read_calibration(written).integrity.edited


@pytest.mark.parametrize("version", [max(CALIBRATION_READABLE_VERSIONS) + 1, 99, 3.5, "3"])
def test_a_future_or_unknown_version_is_refused_in_one_line(written, version):
    data = json.loads(written.read_text())
    data["schema_version"] = version
    written.write_text(json.dumps(data))
    with pytest.raises(InvalidInputError) as error:
        read_calibration(written)
    message = str(error.value)
    assert "\n" not in message and f"schema_version {version!r}" in message
    assert ", ".join(map(str, CALIBRATION_READABLE_VERSIONS)) in message
    if version in (max(CALIBRATION_READABLE_VERSIONS) + 1, 99):
        assert "newer" in message
