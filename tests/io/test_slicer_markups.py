"""Slicer markups files read as needle plans and fiducials, against what Slicer writes and its schema."""

import copy
import json
from pathlib import Path

import numpy as np
import pytest

from spacecal.core.errors import InvalidInputError
from spacecal.io.slicer_markups import (
    fiducials_from_markups,
    plan_from_markups,
    read_markups,
    write_markups,
)

DATA = Path(__file__).parent / "data"
SCHEMAS = {v: DATA / f"markups-schema-v1.0.{v}.json" for v in (0, 3)}
SLICER_FILES = [DATA / "slicer_docs_point_list.mrk.json", DATA / "slicer_line.mrk.json"]


def _schema_version(data):
    return 0 if "v1.0.0" in data["@schema"] else 3


def _required_fields_hold(instance, schema):
    """What the schema requires, checked by hand: required keys, enums, and 3-number positions."""
    for key in schema.get("required", []):
        assert key in instance, key
    for key, sub in schema.get("properties", {}).items():
        if key in instance and "enum" in sub:
            assert instance[key] in sub["enum"], (key, instance[key])
    markup_schema = schema["properties"]["markups"]["items"]["anyOf"][0]
    point_schema = markup_schema["properties"]["controlPoints"]["items"]["anyOf"][0]
    for markup in instance["markups"]:
        for key in markup_schema["required"]:
            assert key in markup
        for key, sub in markup_schema["properties"].items():
            if key in markup and "enum" in sub:
                assert markup[key] in sub["enum"], (key, markup[key])
        for point in markup.get("controlPoints", []):
            for key in point_schema.get("required", []):
                assert key in point
            assert len(point["position"]) == 3


@pytest.mark.parametrize("path", SLICER_FILES, ids=lambda p: p.name)
def test_the_slicer_samples_meet_slicers_schema(path):
    data = json.loads(path.read_text())
    schema = json.loads(SCHEMAS[_schema_version(data)].read_text())
    assert schema["properties"]["markups"]["items"]["anyOf"][0]["properties"]["coordinateSystem"]["enum"] == [
        "LPS",
        "RAS",
    ]
    _required_fields_hold(data, schema)


@pytest.mark.parametrize("path", SLICER_FILES, ids=lambda p: p.name)
def test_the_slicer_samples_validate_with_jsonschema(path):
    jsonschema = pytest.importorskip("jsonschema")
    data = json.loads(path.read_text())
    jsonschema.validate(data, json.loads(SCHEMAS[_schema_version(data)].read_text()))


def test_slicers_documented_point_list_reads_in_lps():
    (markup,) = read_markups(DATA / "slicer_docs_point_list.mrk.json")
    assert markup.kind == "Fiducial" and markup.labels == ("F-1", "F-2", "F-3")
    assert np.array_equal(markup.points_in_image_lps[1], [49.8682950191571, -88.58955938697324, 0.0])
    fiducials = fiducials_from_markups(DATA / "slicer_docs_point_list.mrk.json")
    assert list(fiducials) == ["F-1", "F-2", "F-3"]


def test_a_slicer_line_is_entry_then_target():
    plan = plan_from_markups(DATA / "slicer_line.mrk.json")
    assert plan.image_frame == "image_lps" and (plan.entry_label, plan.target_label) == ("L-1", "L-2")
    assert np.array_equal(plan.entry_in_image, [-31.25, 42.5, 118.75])
    assert np.array_equal(plan.target_in_image, [-12.5, 61.25, 62.5])
    # the length Slicer's own measurement stored in the file
    stored = json.loads((DATA / "slicer_line.mrk.json").read_text())["markups"][0]["measurements"][0]
    assert plan.length_mm == pytest.approx(stored["value"], abs=1e-9)
    # the line's ends named the other way round reverse it
    reversed_plan = plan_from_markups(DATA / "slicer_line.mrk.json", entry_label="L-2", target_label="L-1")
    assert np.array_equal(reversed_plan.entry_in_image, plan.target_in_image)


def _markups(tmp_path, markup, schema="1.0.3", name="m.mrk.json"):
    path = tmp_path / name
    schema_url = f"https://raw.githubusercontent.com/slicer/slicer/master/Modules/Loadable/Markups/Resources/Schema/markups-schema-v{schema}.json#"
    path.write_text(json.dumps({"@schema": schema_url, "markups": [markup]}))
    return path


def _point_list(points, system="LPS", **extra):
    return {
        "type": "Fiducial",
        "coordinateSystem": system,
        "coordinateUnits": "mm",
        "controlPoints": [{"label": label, "position": list(p)} for label, p in points.items()],
        **extra,
    }


def test_ras_and_lps_of_the_same_point_give_the_same_plan(tmp_path):
    entry_lps, target_lps = np.array([10.0, -20.0, 30.0]), np.array([15.0, -5.0, -40.0])
    flip = np.array([-1.0, -1.0, 1.0])
    lps = _markups(tmp_path, _point_list({"entry": entry_lps, "target": target_lps}), name="lps.mrk.json")
    ras = _markups(
        tmp_path,
        _point_list({"entry": entry_lps * flip, "target": target_lps * flip}, "RAS"),
        name="ras.mrk.json",
    )
    a, b = plan_from_markups(lps), plan_from_markups(ras)
    assert np.array_equal(a.entry_in_image, entry_lps) and np.array_equal(b.entry_in_image, entry_lps)
    assert np.array_equal(a.target_in_image, b.target_in_image)


def test_a_line_and_the_equivalent_point_list_give_the_same_plan(tmp_path):
    line = json.loads((DATA / "slicer_line.mrk.json").read_text())["markups"][0]
    points = {"target": line["controlPoints"][1]["position"], "entry": line["controlPoints"][0]["position"]}
    from_line = plan_from_markups(DATA / "slicer_line.mrk.json")
    from_points = plan_from_markups(_markups(tmp_path, _point_list(points)))
    assert np.array_equal(from_line.entry_in_image, from_points.entry_in_image)
    assert np.array_equal(from_line.target_in_image, from_points.target_in_image)


@pytest.mark.parametrize("version", ["1.0.0", "1.0.1", "1.0.2", "1.0.3"])
def test_every_schema_version_slicer_writes_reads(tmp_path, version):
    plan = plan_from_markups(
        _markups(tmp_path, _point_list({"entry": (0, 0, 0), "target": (0, 0, 50)}), version)
    )
    assert plan.length_mm == 50.0


def test_labels_are_chosen_by_default_or_by_option(tmp_path):
    points = {"Start": (0, 0, 0), "Tumour": (0, 0, 80), "Skin": (0, 10, 0)}
    path = _markups(tmp_path, _point_list(points))
    with pytest.raises(InvalidInputError, match="no control point labelled 'target'.*--target-label"):
        plan_from_markups(path)
    plan = plan_from_markups(path, entry_label="skin", target_label="Tumour")
    assert np.array_equal(plan.entry_in_image, [0, 10, 0]) and plan.length_mm == pytest.approx(
        np.hypot(10, 80)
    )


def _one_line(call, match):
    with pytest.raises(InvalidInputError, match=match) as caught:
        call()
    assert "\n" not in str(caught.value)


def test_no_coordinate_system_is_refused_unless_stated(tmp_path):
    markup = _point_list({"entry": (1, 2, 3), "target": (1, 2, 60)})
    del markup["coordinateSystem"]
    path = _markups(tmp_path, markup)
    _one_line(lambda: plan_from_markups(path), "no coordinateSystem.*--coordinate-system")
    assert np.array_equal(plan_from_markups(path, coordinate_system="RAS").entry_in_image, [-1, -2, 3])
    assert np.array_equal(plan_from_markups(path, coordinate_system="LPS").entry_in_image, [1, 2, 3])


def test_an_unknown_coordinate_system_is_refused(tmp_path):
    path = _markups(tmp_path, _point_list({"entry": (1, 2, 3), "target": (1, 2, 60)}, "IJK"))
    _one_line(lambda: plan_from_markups(path), "coordinateSystem 'IJK' is not LPS or RAS")


@pytest.mark.parametrize("units", ["um", "cm", ["um", "UCUM", "micrometer"], ["mm", "DCM", "millimeter"]])
def test_units_other_than_mm_are_refused(tmp_path, units):
    path = _markups(tmp_path, _point_list({"entry": (1, 2, 3), "target": (1, 2, 60)}, coordinateUnits=units))
    _one_line(lambda: plan_from_markups(path), "millimetres only")


def test_coded_millimetres_read(tmp_path):
    markup = _point_list(
        {"entry": (1, 2, 3), "target": (1, 2, 60)}, coordinateUnits=["mm", "UCUM", "millimeter"]
    )
    assert plan_from_markups(_markups(tmp_path, markup)).length_mm == 57.0


def test_bad_markups_files_are_refused_in_one_line(tmp_path):
    good = _point_list({"entry": (1, 2, 3), "target": (1, 2, 60)})
    no_schema = tmp_path / "x.mrk.json"
    no_schema.write_text(json.dumps({"markups": [good]}))
    _one_line(lambda: plan_from_markups(no_schema), "not a Slicer markups file")
    undefined = copy.deepcopy(good)
    undefined["controlPoints"][1] = {"label": "target", "position": "", "positionStatus": "undefined"}
    _one_line(lambda: plan_from_markups(_markups(tmp_path, undefined)), "target .* no defined position")
    bad_position = copy.deepcopy(good)
    bad_position["controlPoints"][0]["position"] = [1, 2]
    _one_line(lambda: plan_from_markups(_markups(tmp_path, bad_position)), "position must be 3 numbers")
    same = _point_list({"entry": (1, 2, 3), "target": (1, 2, 3.5)})
    _one_line(lambda: plan_from_markups(_markups(tmp_path, same)), "apart")
    two = tmp_path / "two.mrk.json"
    schema = json.loads(_markups(tmp_path, good).read_text())["@schema"]
    two.write_text(json.dumps({"@schema": schema, "markups": [dict(good, name="a"), dict(good, name="b")]}))
    _one_line(lambda: plan_from_markups(two), "2 markups could be the plan.*--markup")
    assert plan_from_markups(two, markup_name="b").name == "b"


def test_fiducial_labels_must_pair(tmp_path):
    twice = {
        "type": "Fiducial",
        "coordinateSystem": "LPS",
        "controlPoints": [{"label": "F-1", "position": [0, 0, 0]}, {"label": "F-1", "position": [1, 0, 0]}],
    }
    _one_line(lambda: fiducials_from_markups(_markups(tmp_path, twice)), "two fiducials are labelled 'F-1'")


@pytest.mark.parametrize("kind, system", [("Line", "LPS"), ("Line", "RAS"), ("Fiducial", "LPS")])
def test_written_markups_meet_slicers_schema_and_read_back(tmp_path, kind, system):
    points = {"entry": np.array([10.5, -20.25, 30.0]), "target": np.array([12.0, -25.0, -15.5])}
    if kind == "Fiducial":
        points["F-3"] = np.array([-40.0, 2.0, 7.0])
    path = write_markups(tmp_path / "written.mrk.json", points, kind, system, name="T-1")
    data = json.loads(path.read_text())
    _required_fields_hold(data, json.loads(SCHEMAS[3].read_text()))
    (markup,) = read_markups(path)
    assert markup.kind == kind and markup.name == "T-1" and markup.coordinate_system == system
    assert np.allclose(markup.points_in_image_lps, np.array(list(points.values())))
    plan = plan_from_markups(path)
    assert np.allclose(plan.entry_in_image, points["entry"])
    assert np.allclose(plan.target_in_image, points["target"])
    jsonschema = pytest.importorskip("jsonschema", reason="the hand check above stands without it")
    jsonschema.validate(data, json.loads(SCHEMAS[3].read_text()))


def test_a_markup_that_cannot_be_written_is_one_line(tmp_path):
    with pytest.raises(InvalidInputError, match="two points"):
        write_markups(tmp_path / "x.mrk.json", {"a": [0, 0, 0]}, "Line")
    with pytest.raises(InvalidInputError, match="finite"):
        write_markups(tmp_path / "x.mrk.json", {"a": [0, 0, np.nan], "b": [1, 2, 3]}, "Line")
    with pytest.raises(InvalidInputError, match="LPS or RAS"):
        write_markups(tmp_path / "x.mrk.json", {"a": [0, 0, 0]}, "Curve")
    assert not (tmp_path / "x.mrk.json").exists()
