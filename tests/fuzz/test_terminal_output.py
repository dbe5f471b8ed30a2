"""Names from files, bags and devices reach the terminal escaped and bounded: one error line,
doctor findings and the bag listing carry no raw control characters."""

import importlib

import numpy as np
import pytest

from spacecal.core.ports import FINDING_PROBLEM, FINDING_WARNING, DeviceFinding

cli = importlib.import_module("spacecal.cli.main")  # the module (spacecal.cli.main is also the function)
ESCAPES = "\x1b[2J\x1b]0;owned\x07\x9b31m\u202e\r"


def _inert(text):
    return not any(c in text for c in "\x1b\x07\x9b\u202e\r")


def test_an_error_naming_a_hostile_file_is_one_inert_line(tmp_path, capsys):
    code = cli.main(["report", str(tmp_path / f"cal{ESCAPES}.json"), "-o", str(tmp_path / "r.html")])
    err = capsys.readouterr().err
    assert code == 1 and err.count("\n") == 1 and _inert(err)
    assert "\\x1b[2J" in err


def test_a_huge_error_is_cut(tmp_path, capsys):
    deep = tmp_path.joinpath(*["d" * 200] * 15) / "cal.json"  # a 3,000-character path
    code = cli.main(["report", str(deep), "-o", str(tmp_path / "r.html")])
    err = capsys.readouterr().err
    assert code == 1 and err.count("\n") == 1 and err.rstrip().endswith("...")
    assert len(err) <= len("spacecal: error: ") + cli.ERROR_CHARS + 1


def test_a_hostile_frame_name_is_refused_before_anything_is_written(tmp_path, capsys):
    hostile = 'x"""+__import__("os").system("touch ' + str(tmp_path / "owned") + '")+"""'
    for flag in ("--tracker-frame", "--base-frame"):
        code = cli.main(
            [
                "export",
                str(tmp_path / "cal.json"),
                "--ros2-launch",
                str(tmp_path / "c.launch.py"),
                flag,
                hostile,
            ]
        )
        err = capsys.readouterr().err
        assert code == 1 and err.count("\n") == 1 and f"error: {flag} " in err
    assert list(tmp_path.iterdir()) == []


def test_doctor_findings_are_printed_inert(monkeypatch, capsys):
    findings = [
        ("tracker", DeviceFinding(FINDING_WARNING, "tool", f"device {ESCAPES} streams")),
        ("robot", DeviceFinding(FINDING_PROBLEM, f"name{ESCAPES}", "x" * 10_000)),
    ]
    monkeypatch.setattr(cli.app, "doctor", lambda settings: cli.app.doctor_result(findings))
    code = cli.main(["doctor", "--tracker", "igtl://localhost:18944"])
    out = capsys.readouterr().out
    assert code == 1 and _inert(out)
    assert len(out.splitlines()) == 2 and all(len(line) <= cli.ERROR_CHARS for line in out.splitlines())


def test_a_bag_listing_with_hostile_names_is_inert(tmp_path, capsys):
    pytest.importorskip("rosbags")
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    t = store.types
    bag = tmp_path / "bag"
    with Writer(bag, version=9) as writer:
        connection = writer.add_connection("/tf", "tf2_msgs/msg/TFMessage", typestore=store)
        for k in range(3):
            stamped = t["geometry_msgs/msg/TransformStamped"](
                header=t["std_msgs/msg/Header"](
                    stamp=t["builtin_interfaces/msg/Time"](sec=k, nanosec=0), frame_id="world\x1b[31m"
                ),
                child_frame_id=f"tool{ESCAPES}",
                transform=t["geometry_msgs/msg/Transform"](
                    translation=t["geometry_msgs/msg/Vector3"](x=float(k), y=0.0, z=0.0),
                    rotation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                ),
            )
            message = t["tf2_msgs/msg/TFMessage"](transforms=[stamped])
            writer.write(connection, k, store.serialize_cdr(message, "tf2_msgs/msg/TFMessage"))
    code = cli.main(["import-bag", str(bag), "--list"])
    out = capsys.readouterr().out
    assert code == 0 and _inert(out) and "world\\x1b[31m -> tool\\x1b[2J" in out
    assert np.all([len(line) < 400 for line in out.splitlines()])


def test_bag_errors_list_few_names_escaped():
    from spacecal.core.errors import InvalidInputError
    from spacecal.io import ros_bag

    edges = {(f"world{ESCAPES}", f"frame{k}{ESCAPES}"): ros_bag._EdgeSeries() for k in range(1000)}
    with pytest.raises(InvalidInputError) as caught:
        ros_bag._chain(edges, "base", "tool0", "bag")
    message = str(caught.value)
    assert _inert(message) and "(1001 in all)" in message and len(message) < 2000


def test_progress_shows_a_plan_file_move_label_inert(capsys):
    cli._progress(3)(0, 0, 1, f"sweep{ESCAPES}" + "x" * 500)
    err = capsys.readouterr().err
    assert _inert(err.rstrip("\n")) and "sweep\\x1b[2J" in err and len(err) < 200
