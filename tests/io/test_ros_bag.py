"""ROS bags written with rosbags' own writers (ROS 1, ROS 2 sqlite3 and mcap) from a simulated run,
read back, paired at the estimated clock offset and calibrated: the same numbers as the simulation."""

import sys

import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from spacecal.core.errors import InvalidInputError, MissingExtraError
from spacecal.estimators import calibrate
from spacecal.estimators.time_offset import estimate_time_offset, pair_streams
from spacecal.experiments.simulation import simulate_raw
from spacecal.geometry.transforms import invert_transform, make_transform, matrix_to_rotvec
from spacecal.io.ros_bag import list_bag_contents, read_ros_bag
from spacecal.io.ros_common import transform_to_ros
from spacecal.models.kinematics import forward_kinematics
from spacecal.models.robot_kinds import robot_kind
from spacecal.records import RawRecording
from spacecal.sim.scenario import load_scenario

EPOCH_NS = 1_700_000_000 * 1_000_000_000  # a realistic ROS time: the reader must keep ns precision
CLOCK_OFFSET_S = 0.03
UR_JOINTS = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint"]
UR_JOINTS += ["wrist_3_joint"]


@pytest.fixture(scope="module")
def simulated():
    raw, world = simulate_raw(load_scenario("paper-white"), clock_offset_s=CLOCK_OFFSET_S)
    # What a bag can carry: no marker RMS; stamps in whole nanoseconds, counted from the
    # earliest stamp in the bag (as the reader returns them).
    origin = min(raw.robot_time_s[0], raw.tracker_time_s[0])
    expected = RawRecording(
        robot_time_s=np.round((raw.robot_time_s - origin) * 1e9) * 1e-9,
        robot_segment=raw.robot_segment,
        joints_rad=raw.joints_rad,
        base_from_tcp_stack=raw.base_from_tcp_stack,
        tracker_time_s=np.round((raw.tracker_time_s - origin) * 1e9) * 1e-9,
        tracker_from_marker_stack=raw.tracker_from_marker_stack,
        marker_rms_mm=np.full(len(raw.tracker_time_s), np.nan),
        metadata=raw.metadata,
    )
    return expected, world


class Messages:
    """Builds the few messages the tests need for one type store (ROS 1 headers have ``seq``)."""

    def __init__(self, store):
        self.store = store
        self.t = store.types

    def header(self, stamp_ns, frame):
        time = self.t["builtin_interfaces/msg/Time"](
            sec=int(stamp_ns // 10**9), nanosec=int(stamp_ns % 10**9)
        )
        fields = self.t["std_msgs/msg/Header"].__dataclass_fields__
        if "seq" in fields:
            return self.t["std_msgs/msg/Header"](seq=0, stamp=time, frame_id=frame)
        return self.t["std_msgs/msg/Header"](stamp=time, frame_id=frame)

    def transform(self, matrix):
        xyz, q = transform_to_ros(matrix)
        return self.t["geometry_msgs/msg/Transform"](
            translation=self.t["geometry_msgs/msg/Vector3"](x=xyz[0], y=xyz[1], z=xyz[2]),
            rotation=self.t["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
        )

    def tf(self, stamp_ns, parent, child, matrix):
        stamped = self.t["geometry_msgs/msg/TransformStamped"](
            header=self.header(stamp_ns, parent), child_frame_id=child, transform=self.transform(matrix)
        )
        return self.t["tf2_msgs/msg/TFMessage"](transforms=[stamped])

    def pose(self, stamp_ns, frame, matrix):
        if not np.all(np.isfinite(matrix)):
            xyz, q = np.full(3, np.nan), np.array([0.0, 0.0, 0.0, 1.0])
        else:
            xyz, q = transform_to_ros(matrix)
        pose = self.t["geometry_msgs/msg/Pose"](
            position=self.t["geometry_msgs/msg/Point"](x=xyz[0], y=xyz[1], z=xyz[2]),
            orientation=self.t["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
        )
        return self.t["geometry_msgs/msg/PoseStamped"](header=self.header(stamp_ns, frame), pose=pose)

    def joints(self, stamp_ns, q):
        # The UR ROS 1 driver publishes the joints in another order than the kinematic one.
        order = [2, 0, 1, 3, 4, 5]
        empty = np.zeros(0)
        return self.t["sensor_msgs/msg/JointState"](
            header=self.header(stamp_ns, ""),
            name=[UR_JOINTS[k] for k in order],
            position=np.asarray(q, float)[order],
            velocity=empty,
            effort=empty,
        )


def _stamps(times_s):
    return EPOCH_NS + np.round(np.asarray(times_s) * 1e9).astype(np.int64)


def _messages(raw, world, robot="tf", marker="pose", static=True, rename=None):
    """(topic, msgtype, stamp ns, builder) for every message of the bag, in time order; tf frames
    base, flange, tcp, tracker and marker, or the names ``rename`` gives them."""
    flange_from_tcp = world.nominal_model.flange_from_tcp
    out = []
    if rename:

        class Renamed(Messages):
            def __init__(self, messages):
                self.__dict__.update(messages.__dict__)

            def tf(self, stamp_ns, parent, child, matrix):
                return Messages.tf(
                    self, stamp_ns, rename.get(parent, parent), rename.get(child, child), matrix
                )

        return [
            (topic, msgtype, ns, lambda m, make=make: make(Renamed(m)))
            for topic, msgtype, ns, make in _messages(raw, world, robot, marker, static)
        ]
    if robot == "tf":
        base_from_flange = raw.base_from_tcp_stack @ invert_transform(flange_from_tcp)
        out += [
            ("/tf", "tf2_msgs/msg/TFMessage", ns, lambda m, ns=ns, pose=p: m.tf(ns, "base", "flange", pose))
            for ns, p in zip(_stamps(raw.robot_time_s), base_from_flange)
        ]
        if static:
            out.append(
                (
                    "/tf_static",
                    "tf2_msgs/msg/TFMessage",
                    EPOCH_NS,
                    lambda m: m.tf(EPOCH_NS, "flange", "tcp", flange_from_tcp),
                )
            )
    else:
        out += [
            ("/joint_states", "sensor_msgs/msg/JointState", ns, lambda m, ns=ns, q=q: m.joints(ns, q))
            for ns, q in zip(_stamps(raw.robot_time_s), raw.joints_rad)
        ]
    if marker == "pose":
        out += [
            (
                "/tracker/marker",
                "geometry_msgs/msg/PoseStamped",
                ns,
                lambda m, ns=ns, p=p: m.pose(ns, "tracker", p),
            )
            for ns, p in zip(_stamps(raw.tracker_time_s), raw.tracker_from_marker_stack)
        ]
    else:
        seen = np.all(np.isfinite(raw.tracker_from_marker_stack[:, :3, 3]), axis=1)
        out += [
            ("/tf", "tf2_msgs/msg/TFMessage", ns, lambda m, ns=ns, p=p: m.tf(ns, "tracker", "marker", p))
            for ns, p in zip(_stamps(raw.tracker_time_s[seen]), raw.tracker_from_marker_stack[seen])
        ]
    return sorted(out, key=lambda item: item[2])


def write_ros1(path, raw, world, **kinds):
    store = get_typestore(Stores.ROS1_NOETIC)
    # Noetic's standard store lacks tf2_msgs; a ROS 1 bag embeds the definition anyway.
    store.register(
        get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage")
    )
    build = Messages(store)
    with Writer1(path) as writer:
        connections = {}
        for topic, msgtype, ns, make in _messages(raw, world, **kinds):
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(connections[topic], int(ns), store.serialize_ros1(make(build), msgtype))
    return path


def write_ros2(path, raw, world, storage, **kinds):
    store = get_typestore(Stores.ROS2_HUMBLE)
    build = Messages(store)
    with Writer2(path, version=9, storage_plugin=storage) as writer:
        connections = {}
        for topic, msgtype, ns, make in _messages(raw, world, **kinds):
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(connections[topic], int(ns), store.serialize_cdr(make(build), msgtype))
    return path


def _same_streams(read, expected, robot_poses=True):
    assert np.max(np.abs(read.robot_time_s - expected.robot_time_s)) < 1e-12
    assert np.max(np.abs(read.tracker_time_s - expected.tracker_time_s)) < 1e-12
    if robot_poses:
        assert np.max(np.abs(read.base_from_tcp_stack - expected.base_from_tcp_stack)) < 1e-9
    seen = np.isfinite(expected.tracker_from_marker_stack[:, 0, 3])
    assert np.array_equal(np.isfinite(read.tracker_from_marker_stack[:, 0, 3]), seen)
    assert (
        np.max(np.abs(read.tracker_from_marker_stack[seen] - expected.tracker_from_marker_stack[seen])) < 1e-9
    )


def _chi_square_of_error(result, truth):
    """Mahalanobis distance of the tracker_from_base error under the result's own covariance (6 dof)."""
    error = np.concatenate(
        [
            result.tracker_from_base[:3, 3] - truth[:3, 3],
            matrix_to_rotvec(result.tracker_from_base[:3, :3] @ truth[:3, :3].T),
        ]
    )
    covariance = np.asarray(result.covariance["matrix"])[:6, :6]
    return float(error @ np.linalg.solve(covariance, error))


def test_ros1_bag_tf_robot_and_pose_marker_calibrates_like_the_simulation(tmp_path, simulated):
    expected, world = simulated
    path = write_ros1(tmp_path / "run.bag", expected, world)
    raw = read_ros_bag(path, metadata=expected.metadata)  # one tf chain, one PoseStamped: no names needed
    assert raw.metadata["ros_bag"]["robot"] == {"tf": True, "base_frame": "base", "tool_frame": "tcp"}
    assert raw.metadata["ros_bag"]["time_origin_ns"] == EPOCH_NS
    _same_streams(raw, expected)
    assert np.all(np.isnan(raw.joints_rad)) and np.all(np.isnan(raw.marker_rms_mm))

    estimate = estimate_time_offset(raw)
    assert abs(estimate.offset_s - CLOCK_OFFSET_S) < 0.002
    from_bag = calibrate(pair_streams(raw, estimate.offset_s), "ml")
    direct = calibrate(pair_streams(expected, estimate.offset_s), "ml")
    assert np.max(np.abs(from_bag.tracker_from_base - direct.tracker_from_base)) < 1e-6
    assert np.max(np.abs(from_bag.tcp_from_marker - direct.tcp_from_marker)) < 1e-6
    # and the answer is right within what the injected noise allows (99.99 % of chi-square(6))
    assert _chi_square_of_error(from_bag, world.tracker_from_base) < chi2.ppf(0.9999, 6)


@pytest.mark.parametrize("storage", [StoragePlugin.SQLITE3, StoragePlugin.MCAP], ids=["sqlite3", "mcap"])
def test_ros2_bag_joint_states_through_spacecal_kinematics(tmp_path, simulated, storage):
    expected, world = simulated
    path = write_ros2(tmp_path / "run", expected, world, storage, robot="joints")
    raw = read_ros_bag(path, robot_model=world.nominal_model, metadata=expected.metadata)
    assert raw.metadata["ros_bag"]["robot"]["topic"] == "/joint_states"
    _same_streams(raw, expected)
    assert np.max(np.abs(raw.joints_rad - expected.joints_rad)) < 1e-12
    offset = CLOCK_OFFSET_S
    from_bag = calibrate(pair_streams(raw, offset), "ml")
    direct = calibrate(pair_streams(expected, offset), "ml")
    assert np.max(np.abs(from_bag.tracker_from_base - direct.tracker_from_base)) < 1e-6
    assert _chi_square_of_error(from_bag, world.tracker_from_base) < chi2.ppf(0.9999, 6)


def test_bare_storage_files_and_tf_marker_with_named_frames(tmp_path, simulated):
    expected, world = simulated
    folder = write_ros2(tmp_path / "run", expected, world, StoragePlugin.MCAP, marker="tf")
    (bare,) = folder.glob("*.mcap")
    contents = list_bag_contents(bare)
    assert {(t.name, t.msgtype) for t in contents.topics} == {
        ("/tf", "tf2_msgs/msg/TFMessage"),
        ("/tf_static", "tf2_msgs/msg/TFMessage"),
    }
    edges = {(e.parent, e.child): e for e in contents.tf_edges}
    assert (
        edges[("base", "flange")].count == len(expected.robot_time_s) and not edges[("base", "flange")].static
    )
    assert edges[("flange", "tcp")].static
    assert sorted(contents.tf_chains()) == [("base", "tcp"), ("tracker", "marker")]
    assert "tracker -> marker" in contents.describe()
    # two moving chains, told apart by their frame names
    picked = read_ros_bag(bare)
    assert picked.metadata["ros_bag"]["picked"] == (
        "picked the tf chains robot base -> tcp and marker tracker -> marker (by their frame names; "
        "base_frame='base' tool_frame='tcp' tracker_frame='tracker' marker_frame='marker')"
    )
    assert np.max(np.abs(picked.base_from_tcp_stack - expected.base_from_tcp_stack)) < 1e-9
    raw = read_ros_bag(
        bare, tracker_frame="tracker", marker_frame="marker"
    )  # the robot chain is then obvious
    seen = np.isfinite(expected.tracker_from_marker_stack[:, 0, 3])
    assert len(raw.tracker_time_s) == seen.sum()
    assert np.max(np.abs(raw.tracker_from_marker_stack - expected.tracker_from_marker_stack[seen])) < 1e-9
    assert np.max(np.abs(raw.base_from_tcp_stack - expected.base_from_tcp_stack)) < 1e-9


def test_ambiguous_and_wrong_names_are_one_clear_line(tmp_path, simulated):
    expected, world = simulated
    path = write_ros2(tmp_path / "run", expected, world, StoragePlugin.SQLITE3, robot="joints")
    with pytest.raises(InvalidInputError, match="robot model|robot tf chain") as info:
        read_ros_bag(path)  # joint states but no model, and no tf
    assert "\n" not in str(info.value) and "/joint_states" in str(info.value)
    with pytest.raises(InvalidInputError, match="not the tracker frame 'optical'"):
        read_ros_bag(path, robot_model="UR10", tracker_frame="optical")
    with pytest.raises(InvalidInputError, match="marker topic /nope is absent"):
        read_ros_bag(path, robot_model="UR10", marker_topic="/nope")
    with pytest.raises(InvalidInputError, match="no such bag"):
        read_ros_bag(tmp_path / "missing.bag")


def test_missing_rosbags_names_the_extra(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "rosbags.highlevel", None)
    (tmp_path / "x.bag").write_bytes(b"")
    with pytest.raises(MissingExtraError, match=r"spacecal\[ros\]"):
        list_bag_contents(tmp_path / "x.bag")


def _without_definitions(folder):
    """Drop the embedded message definitions, as in bags recorded before ROS 2 stored them."""
    import sqlite3

    (database,) = folder.glob("*.db3")
    with sqlite3.connect(database) as connection:
        connection.execute("DELETE FROM message_definitions")
    return folder


def test_bags_without_definitions_use_the_standard_type_store(tmp_path):
    rng = np.random.default_rng(2)
    times = np.arange(20) * 0.05
    joints = rng.uniform(-2.0, 2.0, (20, 6))
    model = robot_kind("UR10").model()
    markers = make_transform(Rotation.random(20, random_state=4).as_matrix(), rng.normal(0.0, 500.0, (20, 3)))
    raw = RawRecording(
        times,
        np.array(["x"] * 20),
        joints,
        forward_kinematics(model, joints),
        times,
        markers,
        np.full(20, np.nan),
    )
    world = type("World", (), {"nominal_model": model})()
    folder = _without_definitions(
        write_ros2(tmp_path / "old", raw, world, StoragePlugin.SQLITE3, robot="joints")
    )
    read = read_ros_bag(folder, robot_model="UR10")
    assert np.max(np.abs(read.base_from_tcp_stack - raw.base_from_tcp_stack)) < 1e-9
    assert np.max(np.abs(read.tracker_from_marker_stack - markers)) < 1e-9
    with pytest.raises(
        InvalidInputError, match="has type .*, defined neither in the bag nor in the empty type store"
    ) as info:
        read_ros_bag(folder, robot_model="UR10", typestore="empty")
    assert "\n" not in str(info.value)
    with pytest.raises(InvalidInputError, match="unknown ROS type store 'ros3'"):
        list_bag_contents(folder, typestore="ros3")


def test_the_three_commands_a_ros_user_runs(tmp_path, simulated, capsys):
    """import-bag -> calibrate (offset estimated) -> export for ROS 2, through the command line."""
    from spacecal.cli import main
    from spacecal.io.ros_exports import read_ros2_launch, read_urdf_joint

    expected, world = simulated
    bag = write_ros1(tmp_path / "run.bag", expected, world)
    assert main(["import-bag", str(bag), "--list"]) == 0
    assert "PoseStamped" in capsys.readouterr().out
    assert main(["import-bag", str(bag), "-o", str(tmp_path / "run")]) == 0
    assert (
        main(
            [
                "calibrate",
                str(tmp_path / "run.robot.csv"),
                "--tracker-stream",
                str(tmp_path / "run.tracker.csv"),
                "--method",
                "ml",
                "-o",
                str(tmp_path / "cal.json"),
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    offset_ms = float(out.split("robot clock ")[1].split(" ms")[0])
    assert abs(offset_ms - CLOCK_OFFSET_S * 1000) < 2.0
    assert (
        main(
            [
                "export",
                str(tmp_path / "cal.json"),
                "--ros2-launch",
                str(tmp_path / "cal.launch.py"),
                "--urdf",
                str(tmp_path / "cal.urdf"),
                "--easy-handeye2",
                str(tmp_path / "cal.calib"),
            ]
        )
        == 0
    )
    from spacecal.io.easy_handeye import read_easy_handeye_calibration
    from spacecal.io.results_json import read_calibration

    tracker_from_base = read_calibration(tmp_path / "cal.json").tracker_from_base
    for edge in (read_ros2_launch(tmp_path / "cal.launch.py"), read_urdf_joint(tmp_path / "cal.urdf")):
        # the frame direction users get wrong: parent base, child tracker, matrix base_from_tracker
        assert (edge.parent_frame, edge.child_frame) == ("base", "tracker")
        assert np.allclose(edge.parent_from_child @ tracker_from_base, np.eye(4), atol=1e-6)
    read = read_easy_handeye_calibration(tmp_path / "cal.calib")
    assert np.allclose(read.tracker_from_base, tracker_from_base, atol=1e-6)
    assert main(["export", str(tmp_path / "cal.json"), "--ur-calibration", str(tmp_path / "ur.yaml")]) == 1
    assert "--method kinematic" in capsys.readouterr().err
    # report, bound and check open the recording the calibration came from: two raw streams,
    # paired at the calibration's offset
    capsys.readouterr()
    assert main(["report", str(tmp_path / "cal.json"), "-o", str(tmp_path / "report.html")]) == 0, (
        capsys.readouterr().err
    )
    out = capsys.readouterr().out
    assert "raw streams paired at the calibration's clock offset" in out
    assert "no recording found" not in out
    assert (
        main(
            [
                "bound",
                str(tmp_path / "run.robot.csv"),
                "--calibration",
                str(tmp_path / "cal.json"),
                "--sigma-mm",
                "0.1",
            ]
        )
        == 0
    ), capsys.readouterr().err
    assert main(["check", str(tmp_path / "cal.json"), "--recording", str(tmp_path / "run.robot.csv")]) == 0, (
        capsys.readouterr().err
    )


def test_import_bag_picks_two_chains_it_can_tell_apart_and_lists_the_flags_otherwise(
    tmp_path, simulated, capsys
):
    from spacecal.cli import main

    expected, world = simulated
    named = write_ros2(tmp_path / "named", expected, world, StoragePlugin.MCAP, marker="tf")
    assert main(["import-bag", str(named), "-o", str(tmp_path / "named")]) == 0
    out = capsys.readouterr().out
    assert (
        "picked the tf chains robot base -> tcp and marker tracker -> marker (by their frame names; "
        "--base-frame base --tool-frame tcp --tracker-frame tracker --marker-frame marker)"
    ) in out
    assert (tmp_path / "named.robot.csv").is_file() and (tmp_path / "named.tracker.csv").is_file()

    # names that say nothing: either chain could be the robot's
    rename = {"base": "frame_a", "flange": "a1", "tcp": "a2", "tracker": "frame_b", "marker": "b1"}
    bag = write_ros2(tmp_path / "plain", expected, world, StoragePlugin.MCAP, marker="tf", rename=rename)
    assert main(["import-bag", str(bag), "-o", str(tmp_path / "plain")]) == 1
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1
    assert (
        "cannot choose the robot and marker tf chains (moving tf chains: frame_a -> a2, frame_b -> b1); give "
        "--base-frame frame_a --tool-frame a2 --tracker-frame frame_b --marker-frame b1; or "
        "--base-frame frame_b --tool-frame b1 --tracker-frame frame_a --marker-frame a2"
    ) in err
    for python_name in ("base_frame", "tool_frame", "tracker_frame", "marker_frame", "list_bag_contents"):
        assert python_name not in err
    assert not (tmp_path / "plain.robot.csv").exists()
    # one flag settles it, and the line says what was picked
    assert main(["import-bag", str(bag), "-o", str(tmp_path / "plain"), "--tool-frame", "a2"]) == 0
    assert (
        "picked the tf chains robot frame_a -> a2 and marker frame_b -> b1 (the only way the moving tf "
        "chains fit; --base-frame frame_a --tool-frame a2 --tracker-frame frame_b --marker-frame b1)"
    ) in capsys.readouterr().out


def test_import_bag_errors_name_the_flags(tmp_path, simulated, capsys):
    from spacecal.cli import main

    expected, world = simulated
    joints = write_ros2(tmp_path / "joints", expected, world, StoragePlugin.SQLITE3, robot="joints")
    assert main(["import-bag", str(joints), "-o", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err
    assert "give --joint-states (JointState topics: /joint_states) and --robot-model" in err
    assert "joint_state_topic" not in err and "robot_model" not in err
