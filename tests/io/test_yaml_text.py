"""YAML read strictly (no anchors or aliases, plain decimal numbers) and written by a quoting writer."""

import time
import tracemalloc

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from spacecal.core.errors import InvalidInputError
from spacecal.geometry.transforms import make_transform
from spacecal.io.easy_handeye import (
    easy_handeye2_calibration_text,
    read_easy_handeye_calibration,
    read_easy_handeye_samples,
    write_easy_handeye2_calibration,
)
from spacecal.io.ros_bag import BagContents, BagTopic, TfEdge, list_bag_contents
from spacecal.io.ur_driver_calibration import read_ur_calibration, ur_calibration_text, write_ur_calibration
from spacecal.io.yaml_text import parse_yaml, yaml_comment, yaml_number, yaml_string
from spacecal.models.robot_kinds import robot_kind

FRAMES = {
    "robot_base_frame": "base",
    "robot_effector_frame": "tool0",
    "tracking_base_frame": "polaris",
    "tracking_marker_frame": "marker",
}


def _bomb(levels=9, width=9) -> str:
    """The "billion laughs": each level lists the previous one ``width`` times (9**9 leaves)."""
    lines = ["a0: &a0 [" + ", ".join(['"lol"'] * width) + "]"]
    for k in range(1, levels + 1):
        lines.append(f"a{k}: &a{k} [" + ", ".join([f"*a{k - 1}"] * width) + "]")
    return "\n".join(lines) + "\n"


def test_an_alias_bomb_is_refused_quickly_in_bounded_memory(tmp_path):
    path = tmp_path / "bomb.samples"
    body = _bomb().replace("a0: ", "parameters:\n  name: x\n  calibration_type: *a9\nsamples: []\na0: ", 1)
    path.write_text(body)
    assert path.stat().st_size < 700
    tracemalloc.start()
    start = time.perf_counter()
    try:
        with pytest.raises(InvalidInputError) as caught:
            read_easy_handeye_samples(path)
        elapsed = time.perf_counter() - start
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    message = str(caught.value)
    assert "anchor" in message and "\n" not in message and len(message) < 300
    assert elapsed < 2.0 and peak < 20 * 1024**2


@pytest.mark.parametrize(
    "text",
    [
        "a: &x 1\nb: *x\n",
        "a: &x {k: 1}\n",
        "- &x [1]\n- 2\n",
        "base: &b {x: 1}\nother:\n  <<: *b\n",
        "a: !!str &x text\n",
    ],
)
def test_any_anchor_or_alias_is_refused(text):
    with pytest.raises(InvalidInputError, match="aliases and anchors are not accepted"):
        parse_yaml(text, "f.yaml", "test")


@pytest.mark.parametrize(
    "text,value",
    [
        ("1_000", "1_000"),
        ("0x10", "0x10"),
        ("0o17", "0o17"),
        ("0b11", "0b11"),
        ("1:30", "1:30"),
        ("1_0.5", "1_0.5"),
        ("2001-12-14", "2001-12-14"),
        ("190:20:30.15", "190:20:30.15"),
        ("1e-05", 1e-05),
        ("1.0e-05", 1e-05),
        ("1E5", 100000.0),
        ("-2.373046667922381e-11", -2.373046667922381e-11),
        ("017", 17),
        ("-12", -12),
        (".5", 0.5),
        ("true", True),
        ("~", None),
    ],
)
def test_numbers_are_read_in_plain_decimal_forms_only(text, value):
    assert parse_yaml(f"k: {text}\n", "f.yaml", "test") == {"k": value}


@pytest.mark.parametrize("text", ["!!int 1_000", "!!float 1_0.5", "!!int 0x10", "!!float 1:30"])
def test_explicit_number_tags_are_read_strictly_too(text):
    with pytest.raises(InvalidInputError, match="plain decimal"):
        parse_yaml(f"k: {text}\n", "f.yaml", "test")


def test_a_grouped_number_in_a_calibration_is_one_line(tmp_path):
    path = tmp_path / "c.calib"
    text = easy_handeye2_calibration_text(np.eye(4), name="c", **FRAMES)
    path.write_text(text.replace("x: 0.0", "x: 1_000", 1))
    with pytest.raises(InvalidInputError, match=r"field 'x' is '1_000', expected a finite number"):
        read_easy_handeye_calibration(path)


@pytest.mark.parametrize(
    "value", [1e-05, -3.5e-12, 1e16, 0.0, -0.0, 123.456, 5e-324, 1.7976931348623157e308, 0.1 + 0.2]
)
def test_numbers_are_written_so_yaml_1_1_and_1_2_readers_see_floats(value):
    text = yaml_number(value)
    assert isinstance(yaml.safe_load(f"k: {text}")["k"], float)  # PyYAML, YAML 1.1 (xacro reads it)
    assert yaml.safe_load(f"k: {text}")["k"] == value
    assert parse_yaml(f"k: {text}", "f", "t")["k"] == value


@pytest.mark.parametrize(
    "value",
    [
        "base",
        "ur/base",
        "yes",
        "No",
        "null",
        "y",
        "N",
        "1_000",
        "0x10",
        "2001-12-14",
        "",
        "a: b",
        "#c",
        "- x",
        '"q"',
        "'s'",
        "x\ny",
        "\u2028",
        "caf\u00e9",
        "\x00",
        "\U0001f600",
        " lead",
        "trail ",
        "&a",
        "*a",
        "!t",
    ],
)
def test_strings_are_written_so_every_reader_reads_the_same_string(value):
    text = yaml_string(value)
    assert text.isascii() and "\n" not in text
    assert yaml.safe_load(f"k: {text}")["k"] == value
    assert parse_yaml(f"k: {text}", "f", "t")["k"] == value


def test_small_translations_survive_a_yaml_1_1_reader(tmp_path):
    tracker_from_base = make_transform(
        Rotation.from_rotvec([0.1, 0.2, 0.3]).as_matrix(), [0.01, -0.002, 3e-9]
    )
    path = write_easy_handeye2_calibration(tmp_path / "tiny.calib", tracker_from_base, **FRAMES)
    data = yaml.safe_load(path.read_text())
    assert all(isinstance(v, float) for v in data["transform"]["translation"].values())
    assert np.allclose(read_easy_handeye_calibration(path).tracker_from_base, tracker_from_base, atol=1e-12)


def test_a_model_name_cannot_add_keys_to_the_ur_file(tmp_path):
    model = robot_kind("UR10").model()
    model = type(model)(**{**model.__dict__, "name": "UR10\nhash: calib_0\nevil: 1\r\x85\u2028x"})
    text = ur_calibration_text(model, kinematics_hash="calib_1\nevil: 2")
    data = yaml.safe_load(text)
    assert sorted(data) == ["kinematics", "tool_offset"]
    assert "evil" not in data["kinematics"] and "evil" not in data["tool_offset"]
    assert data["kinematics"]["hash"] == "calib_1\nevil: 2"
    assert text.isascii() and all(
        line.startswith(("#", " ", "kinematics:", "tool_offset:")) for line in text.splitlines()
    )
    path = write_ur_calibration(tmp_path / "k.yaml", model, kinematics_hash="calib_1\nevil: 2")
    assert read_ur_calibration(path).kinematics_hash == "calib_1\nevil: 2"


def test_a_bag_whose_metadata_has_aliases_is_refused(tmp_path):
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information:\n  x: &a [1]\n  y: *a\n")
    with pytest.raises(InvalidInputError, match="ROS 2 bag metadata"):
        list_bag_contents(bag)


def test_bag_listing_shows_names_inert_and_bounded():
    contents = BagContents(
        "bag\x1b]0;title\x07",
        [BagTopic("/marker\x1b[2J", "geometry_msgs/msg/PoseStamped", 3), BagTopic("/" + "t" * 5000, "x", 1)],
        [TfEdge("world\r\n", "tool\u202e0", 2, False)],
    )
    text = contents.describe()
    assert "\x1b" not in text and "\x07" not in text and "\r" not in text and "\u202e" not in text
    assert len(text.splitlines()) == 7  # path, "topics:", 2 topics, "tf edges", 1 edge, 1 chain
    assert max(len(line) for line in text.splitlines()) < 400


def test_yaml_comments_stay_comments():
    comment = yaml_comment("a\nb: 1\r\x85\u2028c")
    assert yaml.safe_load(comment + "\nk: 1\n") == {"k": 1}


def test_a_yaml_file_beyond_the_bound_is_refused_before_it_is_parsed(tmp_path):
    """One huge scalar took PyYAML a minute and 730 MB; the file's size is checked first."""
    from spacecal.io.yaml_text import MAX_YAML_BYTES, load_yaml_mapping

    path = tmp_path / "huge.samples"
    with path.open("w") as out:
        out.write("samples: '")
        out.write("x" * (MAX_YAML_BYTES + 1))
        out.write("'\n")
    started = time.monotonic()
    with pytest.raises(InvalidInputError, match=r"too large for a easy_handeye sample list file"):
        load_yaml_mapping(path, "easy_handeye sample list")
    assert time.monotonic() - started < 1.0
