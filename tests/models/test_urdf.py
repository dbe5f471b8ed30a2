"""Standard DH models from URDF files, checked against yourdfpy's own forward kinematics of the
same files (real UR10, iiwa 14 and Panda descriptions, and random chains) and against the DH
table Universal Robots publishes."""

import io
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from spacecal.core.errors import InvalidInputError, MissingExtraError
from spacecal.geometry.transforms import invert_transform, matrix_to_rotvec
from spacecal.models.kinematics import UR_ALPHA_RAD, UR_TABLES, forward_kinematics, ur_model
from spacecal.models.urdf import joint_speed_limits_from_urdf, robot_model_from_urdf

yourdfpy = pytest.importorskip("yourdfpy")

DATA = Path(__file__).parent / "data" / "urdf"
UR10 = DATA / "ur10_robot.urdf"
IIWA14 = DATA / "iiwa14_no_collision.urdf"
PANDA = DATA / "panda_arm.urdf"

#: The agreement asked of the model: the URDF's own numbers carry no more than this error
#: from the conversion (it works in double precision on lengths of about 1 m).
POSITION_TOL_MM = 1e-6
ROTATION_TOL_RAD = 1e-9
SAMPLES = 60


def reference_pose(urdf, joint_names, joints_rad, base_link, tool_link):
    """yourdfpy's ``base_from_tool`` (4, 4) of the URDF at the joints (named in our order), mm."""
    urdf.update_cfg(dict(zip(joint_names, joints_rad)))
    pose = np.array(urdf.get_transform(frame_to=tool_link, frame_from=base_link), dtype=float)
    pose[:3, 3] *= 1000.0
    return pose


def chain_joint_names(urdf, base_link, tool_link):
    """The moving joints between the two links, base first, from yourdfpy's tree."""
    parent_joint = {joint.child: joint for joint in urdf.robot.joints}

    def up(link):
        path = [link]
        while path[-1] in parent_joint:
            path.append(parent_joint[path[-1]].parent)
        return path

    base_up, tool_up = up(base_link), up(tool_link)
    meet = next(link for link in base_up if link in tool_up)
    joints = [parent_joint[link] for link in base_up[: base_up.index(meet)]]
    joints += [parent_joint[link] for link in reversed(tool_up[: tool_up.index(meet)])]
    return [joint.name for joint in joints if joint.type in ("revolute", "continuous")]


def worst_disagreement(source, base_link, tool_link, model, rng, samples=SAMPLES):
    """Largest position (mm) and rotation (rad) difference between yourdfpy and the DH model
    over random joint vectors within the model's limits."""
    if isinstance(source, Path):
        urdf = yourdfpy.URDF.load(str(source), load_meshes=False)
    else:
        urdf = yourdfpy.URDF.load(io.BytesIO(source.encode()), load_meshes=False)
    names = chain_joint_names(urdf, base_link, tool_link)
    assert len(names) == model.n_joints
    joints = rng.uniform(model.joint_lower_rad, model.joint_upper_rad, (samples, model.n_joints))
    ours = forward_kinematics(model, joints)
    position, rotation = 0.0, 0.0
    for q, pose in zip(joints, ours):
        expected = reference_pose(urdf, names, q, base_link, tool_link)
        position = max(position, float(np.max(np.abs(pose[:3, 3] - expected[:3, 3]))))
        rotation = max(rotation, float(np.linalg.norm(matrix_to_rotvec(expected[:3, :3].T @ pose[:3, :3]))))
    return position, rotation


@pytest.mark.parametrize(
    ("source", "base_link", "tool_link", "joints"),
    [
        (UR10, "base_link", "tool0", 6),
        (UR10, "base", "tool0", 6),
        (UR10, "world", "ee_link", 6),
        (IIWA14, "base", "iiwa_link_ee", 7),
        (IIWA14, "iiwa_link_0", "iiwa_link_ee_kuka", 7),
        (PANDA, "panda_link0", "panda_link8", 7),
        (PANDA, "panda_link0", "panda_link7", 7),
    ],
)
def test_the_dh_model_moves_as_the_urdf_does(source, base_link, tool_link, joints):
    model = robot_model_from_urdf(source, base_link, tool_link)
    assert model.n_joints == joints
    position, rotation = worst_disagreement(source, base_link, tool_link, model, np.random.default_rng(3))
    assert position < POSITION_TOL_MM
    assert rotation < ROTATION_TOL_RAD


def test_joint_limits_and_name_come_from_the_urdf():
    panda = robot_model_from_urdf(PANDA, "panda_link0", "panda_link8")
    assert panda.name == "panda"
    assert np.allclose(panda.joint_lower_rad, [-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973])
    assert np.allclose(panda.joint_upper_rad, [2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973])
    named = robot_model_from_urdf(IIWA14, "base", "iiwa_link_ee", name="iiwa14 cell 2")
    assert named.name == "iiwa14 cell 2"
    assert np.allclose(named.joint_upper_rad[[0, 6]], [2.96705972839, 3.05432619099])


def test_joint_speed_limits_come_from_the_urdf():
    speeds = joint_speed_limits_from_urdf(UR10, "base", "tool0")
    assert np.allclose(speeds, [2.16, 2.16, 3.15, 3.2, 3.2, 3.2])
    assert np.allclose(
        joint_speed_limits_from_urdf(PANDA, "panda_link0", "panda_link8"), [2.175] * 4 + [2.61] * 3
    )
    no_velocity = _two_joints(extra='<limit lower="-1" upper="1" effort="1"/>')
    _refused(no_velocity, "a", "c", "no positive velocity", read=joint_speed_limits_from_urdf)


def test_the_ur10_urdf_gives_the_published_ur10_table():
    # the UR controller's base frame ("base") and all-zero TCP ("tool0"): the DH table of the
    # URDF is Universal Robots' own, joint for joint
    model = robot_model_from_urdf(UR10, "base", "tool0")
    table = UR_TABLES["UR10"]
    assert np.allclose(model.a_mm, table["a"], atol=1e-9)
    assert np.allclose(model.d_mm, table["d"], atol=1e-9)
    assert np.allclose(model.alpha_rad, UR_ALPHA_RAD, atol=1e-10)
    assert np.allclose(model.theta_offset_rad, 0.0, atol=1e-10)
    assert np.allclose(model.flange_from_tcp, np.eye(4), atol=1e-9)
    rng = np.random.default_rng(11)
    joints = rng.uniform(-np.pi, np.pi, (SAMPLES, 6))
    published = forward_kinematics(ur_model("UR10"), joints)
    ours = forward_kinematics(model, joints)
    assert np.max(np.abs(ours[:, :3, 3] - published[:, :3, 3])) < POSITION_TOL_MM
    assert np.max(np.abs(ours[:, :3, :3] - published[:, :3, :3])) < ROTATION_TOL_RAD


def test_from_the_ros_base_link_the_ur10_differs_from_the_table_by_fixed_offsets_only():
    # ROS's base_link is turned half a turn from the controller's base: another DH table (the
    # standard DH ambiguity: signs of a and alpha, a theta offset of pi), same motion
    model = robot_model_from_urdf(UR10, "base_link", "tool0")
    table = UR_TABLES["UR10"]
    assert np.allclose(np.abs(model.a_mm), np.abs(table["a"]), atol=1e-9)
    assert np.allclose(model.d_mm, table["d"], atol=1e-9)
    assert np.allclose(np.abs(model.alpha_rad), np.abs(UR_ALPHA_RAD), atol=1e-10)
    urdf = yourdfpy.URDF.load(str(UR10), load_meshes=False)
    base_link_from_base = np.array(urdf.get_transform(frame_to="base", frame_from="base_link"))
    assert np.allclose(base_link_from_base[:3, 3], 0.0)
    published = ur_model("UR10")
    # the flange offset from the zero pose, then the motion everywhere else is a test
    flange = (
        invert_transform(forward_kinematics(published, np.zeros(6)))
        @ invert_transform(base_link_from_base)
        @ forward_kinematics(model, np.zeros(6))
    )
    # (the URDF's pi to 12 digits turns the base by 1e-11 rad)
    assert np.allclose(flange[:3, :3], np.eye(3), atol=ROTATION_TOL_RAD)
    assert np.allclose(flange[:3, 3], 0.0, atol=POSITION_TOL_MM)
    rng = np.random.default_rng(5)
    joints = rng.uniform(-np.pi, np.pi, (SAMPLES, 6))
    expected = base_link_from_base @ forward_kinematics(published, joints) @ flange
    ours = forward_kinematics(model, joints)
    assert np.max(np.abs(ours[:, :3, 3] - expected[:, :3, 3])) < POSITION_TOL_MM
    assert np.max(np.abs(ours[:, :3, :3] - expected[:, :3, :3])) < ROTATION_TOL_RAD


def test_the_tool_offset_is_what_lies_beyond_the_last_joint():
    # iiwa_link_ee is 45 mm beyond link 7 on its axis, turned -90 deg about y: the last DH frame
    # is on the axis at the tool's origin, the rest a pure rotation
    model = robot_model_from_urdf(IIWA14, "base", "iiwa_link_ee")
    assert np.allclose(model.flange_from_tcp[:3, 3], 0.0, atol=1e-9)
    assert np.isclose(model.d_mm[-1], 81.0 + 45.0)
    assert np.isclose(abs(model.flange_from_tcp[2, 0]), 1.0)
    to_link7 = robot_model_from_urdf(IIWA14, "base", "iiwa_link_7")
    assert np.isclose(to_link7.d_mm[-1], 81.0)
    assert np.allclose(to_link7.d_mm[:6], model.d_mm[:6])


# -- random chains ---------------------------------------------------------------------------


def _rpy_xyz(rng, scale_m=0.4):
    return rng.uniform(-np.pi, np.pi, 3), rng.uniform(-scale_m, scale_m, 3)


def _numbers(values):
    return " ".join(repr(float(v)) for v in values)


def _origin(rpy, xyz):
    return f'<origin rpy="{_numbers(rpy)}" xyz="{_numbers(xyz)}"/>'


LIMIT = '<limit lower="-2.5" upper="2.0" effort="1" velocity="1"/>'


def random_chain_urdf(rng, joints):
    """A URDF of a random serial chain ``base`` -> ``tool``: joint 1 on the base's z axis, then
    revolute and continuous joints at random poses, some with parallel, crossing, antiparallel
    or coincident axes, fixed joints between them, and side branches off the chain."""
    lines = ['<robot name="random_arm">', '<link name="base"/>']
    height = rng.uniform(0.05, 0.3)
    lines.append(
        f'<joint name="j1" type="revolute"><parent link="base"/><child link="l1"/>'
        f"{_origin([0.0, 0.0, rng.uniform(-np.pi, np.pi)], [0.0, 0.0, height])}"
        '<axis xyz="0 0 2"/><limit lower="-3" upper="3" effort="1" velocity="1"/></joint>'
    )
    lines.append('<link name="l1"/>')
    # the previous joint's axis in its child link's frame (the axis is stated in that frame)
    axis = np.array([0.0, 0.0, 1.0])
    for k in range(2, joints + 1):
        parent = f"l{k - 1}"
        previous_axis = axis
        if rng.uniform() < 0.4:  # a fixed joint folded into the chain
            lines.append(
                f'<joint name="f{k}" type="fixed"><parent link="{parent}"/><child link="m{k}"/>'
                f"{_origin(*_rpy_xyz(rng))}</joint>"
            )
            lines.append(f'<link name="m{k}"/>')
            parent = f"m{k}"
            previous_axis = None  # in another frame now: any geometry
        rpy, xyz = _rpy_xyz(rng)
        axis = _unit(rng.normal(size=3))
        kind = rng.choice(["skew", "parallel", "crossing", "antiparallel", "coincident"])
        if previous_axis is not None and kind != "skew":
            # no rotation in the origin: the new axis is stated in the previous joint's axes
            rpy = np.zeros(3)
            if kind == "parallel":
                axis = previous_axis
            elif kind == "antiparallel":
                axis = -previous_axis
            elif kind == "crossing":
                xyz = previous_axis * rng.uniform(-0.3, 0.3)
            else:  # coincident: the same line
                axis = previous_axis
                xyz = previous_axis * rng.uniform(-0.3, 0.3)
        joint_type = "continuous" if rng.uniform() < 0.2 else "revolute"
        limit = "" if joint_type == "continuous" else LIMIT
        # a non-unit axis: the URDF's direction, whatever its length
        stated = axis * rng.uniform(0.5, 2.0)
        lines.append(
            f'<joint name="j{k}" type="{joint_type}"><parent link="{parent}"/><child link="l{k}"/>'
            f'{_origin(rpy, xyz)}<axis xyz="{_numbers(stated)}"/>{limit}</joint>'
        )
        lines.append(f'<link name="l{k}"/>')
        if rng.uniform() < 0.3:  # a side branch (a sensor, a finger) off the chain
            lines.append(
                f'<joint name="b{k}" type="revolute"><parent link="l{k}"/><child link="side{k}"/>'
                f'{_origin(*_rpy_xyz(rng))}<axis xyz="1 0 0"/>{LIMIT}</joint>'
            )
            lines.append(f'<link name="side{k}"/>')
    lines.append(
        f'<joint name="tool_joint" type="fixed"><parent link="l{joints}"/><child link="tool"/>'
        f"{_origin(*_rpy_xyz(rng))}</joint>"
    )
    lines.append('<link name="tool"/>')
    lines.append("</robot>")
    return "\n".join(lines)


def _unit(vector):
    return vector / np.linalg.norm(vector)


@pytest.mark.parametrize("seed", range(12))
def test_random_chains_move_as_the_urdf_does(seed):
    rng = np.random.default_rng(100 + seed)
    joints = int(rng.integers(1, 9))
    text = random_chain_urdf(rng, joints)
    model = robot_model_from_urdf(text, "base", "tool")
    assert model.n_joints == joints
    position, rotation = worst_disagreement(text, "base", "tool", model, rng, samples=50)
    assert position < POSITION_TOL_MM
    assert rotation < ROTATION_TOL_RAD


def test_a_chain_may_run_up_a_moving_joint():
    # from the tool up to the base: every joint turns the other way round its line (joint 2's
    # axis, -z of link c, is +z seen from c running up it)
    text = (
        '<robot name="r"><link name="a"/><link name="b"/><link name="c"/>'
        '<joint name="j1" type="revolute"><parent link="a"/><child link="b"/>'
        '<origin xyz="0.1 0.2 0.3" rpy="0.3 -0.2 0.1"/><axis xyz="0 1 0"/>'
        '<limit lower="-2" upper="2" effort="1" velocity="1"/></joint>'
        '<joint name="j2" type="revolute"><parent link="b"/><child link="c"/>'
        '<origin xyz="0.0 0.4 0.0" rpy="0 0 0"/><axis xyz="0 0 -1"/>'
        '<limit lower="-1" upper="1.5" effort="1" velocity="1"/></joint></robot>'
    )
    model = robot_model_from_urdf(text, "c", "a")
    assert model.n_joints == 2
    assert np.allclose(model.joint_lower_rad, [-1.0, -2.0])
    position, rotation = worst_disagreement(text, "c", "a", model, np.random.default_rng(2), samples=50)
    assert position < POSITION_TOL_MM
    assert rotation < ROTATION_TOL_RAD


@pytest.mark.parametrize("misalignment_rad", [1e-12, 1e-10, 3e-9, 1e-8, 1e-6, 1e-4])
def test_nearly_parallel_axes_stay_within_double_precision_of_dh(misalignment_rad):
    # shoulder and elbow axes parallel but for a small tilt: below 1e-9 taken as parallel, above
    # it the true common normal (its d's up to 1e10 mm); the band between the two costs a few
    # 1e-6 mm, standard DH's own conditioning (measured: 4.2e-6 mm at 3e-9)
    text = (
        '<robot name="r"><link name="a"/><link name="b"/><link name="c"/><link name="d"/>'
        '<joint name="j1" type="revolute"><parent link="a"/><child link="b"/><origin xyz="0 0 0.1"/>'
        '<axis xyz="0 0 1"/><limit lower="-3" upper="3"/></joint>'
        '<joint name="j2" type="revolute"><parent link="b"/><child link="c"/><origin xyz="0 0.1 0"/>'
        '<axis xyz="0 1 0"/><limit lower="-3" upper="3"/></joint>'
        '<joint name="j3" type="revolute"><parent link="c"/><child link="d"/>'
        f'<origin xyz="0.6 0.05 0.1" rpy="{misalignment_rad!r} 0 0"/>'
        '<axis xyz="0 1 0"/><limit lower="-3" upper="3"/></joint></robot>'
    )
    model = robot_model_from_urdf(text, "a", "d")
    position, rotation = worst_disagreement(text, "a", "d", model, np.random.default_rng(4), samples=50)
    assert position < (POSITION_TOL_MM if not 1e-9 < misalignment_rad < 1e-7 else 1e-5)
    assert rotation < ROTATION_TOL_RAD


# -- sources -----------------------------------------------------------------------------------


def test_a_urdf_is_read_from_a_path_a_string_or_bytes():
    text = PANDA.read_text()
    from_path = robot_model_from_urdf(str(PANDA), "panda_link0", "panda_link8")
    for source in (PANDA, text, text.encode()):
        model = robot_model_from_urdf(source, "panda_link0", "panda_link8")
        assert np.allclose(model.d_mm, from_path.d_mm)
        assert np.allclose(model.flange_from_tcp, from_path.flange_from_tcp)


def test_mimic_joints_off_the_chain_are_ignored():
    # a gripper's second finger mimics the first: neither is between base and flange
    hand = (
        '<link name="finger_left"/><link name="finger_right"/>'
        '<joint name="finger_joint1" type="prismatic"><parent link="panda_link8"/>'
        '<child link="finger_left"/><origin xyz="0 0 0.05"/><axis xyz="0 1 0"/>'
        '<limit lower="0" upper="0.04" effort="1" velocity="1"/></joint>'
        '<joint name="finger_joint2" type="prismatic"><parent link="panda_link8"/>'
        '<child link="finger_right"/><origin xyz="0 0 0.05"/><axis xyz="0 -1 0"/>'
        '<limit lower="0" upper="0.04" effort="1" velocity="1"/><mimic joint="finger_joint1"/></joint>'
    )
    text = PANDA.read_text().replace("</robot>", hand + "</robot>")
    with_hand = robot_model_from_urdf(text, "panda_link0", "panda_link8")
    without = robot_model_from_urdf(PANDA, "panda_link0", "panda_link8")
    assert np.allclose(with_hand.d_mm, without.d_mm)
    # and through a finger the chain holds a prismatic joint, refused
    with pytest.raises(InvalidInputError, match="prismatic"):
        robot_model_from_urdf(text, "panda_link0", "finger_left")


# -- bad input, one line each -----------------------------------------------------------------


def _refused(source, base_link, tool_link, match, read=robot_model_from_urdf):
    with pytest.raises(InvalidInputError, match=match) as caught:
        read(source, base_link, tool_link)
    message = str(caught.value)
    assert "\n" not in message and len(message) < 300
    return message


def _two_joints(second_type="revolute", extra=""):
    return (
        '<robot name="r"><link name="a"/><link name="b"/><link name="c"/>'
        '<joint name="j1" type="revolute"><parent link="a"/><child link="b"/>'
        '<origin xyz="0 0 0.1"/><axis xyz="0 0 1"/>'
        '<limit lower="-2" upper="2" effort="1" velocity="1"/></joint>'
        f'<joint name="j2" type="{second_type}"><parent link="b"/><child link="c"/>'
        f'<origin xyz="0.3 0 0"/><axis xyz="0 1 0"/>{extra}</joint></robot>'
    )


def test_what_is_not_a_urdf_is_refused(tmp_path):
    _refused(tmp_path / "missing.urdf", "a", "b", "does not exist")
    text_file = tmp_path / "notes.urdf"
    text_file.write_text("these are not robot descriptions\n")
    _refused(text_file, "a", "b", "not a (readable )?URDF")
    _refused("<robot name='r'><link name='a'>", "a", "b", "not a (readable )?URDF")
    _refused("<scene><thing/></scene>", "a", "b", "not a (readable )?URDF")
    _refused(b"\x00\x01\x02", "a", "b", "not a (readable )?URDF")
    entities = '<?xml version="1.0"?><!DOCTYPE r [<!ENTITY x "0.1">]><robot name="r"><link name="a"/></robot>'
    _refused(entities, "a", "a", "DTD")
    xacro = (
        '<robot xmlns:xacro="http://www.ros.org/wiki/xacro" name="r"><xacro:property name="h" value="1"/>'
        '<link name="a"/></robot>'
    )
    _refused(xacro, "a", "a", "xacro file")


def test_links_that_are_not_there_are_named():
    message = _refused(PANDA, "panda_link0", "panda_hand", "no link 'panda_hand'")
    assert "tool_link" in message
    assert "base_link" in _refused(PANDA, "world", "panda_link8", "no link 'world'")


def test_links_with_no_chain_between_them_are_refused():
    apart = _two_joints(extra='<limit lower="-1" upper="1" effort="1" velocity="1"/>').replace(
        "</robot>", '<link name="elsewhere"/></robot>'
    )
    _refused(apart, "a", "elsewhere", "no kinematic chain")


def test_a_closed_loop_in_the_chain_is_refused():
    loop = _two_joints(extra='<limit lower="-1" upper="1" effort="1" velocity="1"/>').replace(
        "</robot>",
        '<joint name="j3" type="revolute"><parent link="a"/><child link="c"/>'
        '<origin xyz="0.3 0 0.1"/><axis xyz="0 1 0"/>'
        '<limit lower="-1" upper="1" effort="1" velocity="1"/></joint></robot>',
    )
    _refused(loop, "a", "c", "closed loop")


def test_a_mimic_joint_in_the_chain_is_refused():
    mimic = _two_joints(extra='<limit lower="-1" upper="1" effort="1" velocity="1"/><mimic joint="j1"/>')
    _refused(mimic, "a", "c", "mimics 'j1'")


def test_prismatic_floating_and_limitless_joints_in_the_chain_are_refused():
    limit = '<limit lower="0" upper="0.1" effort="1" velocity="1"/>'
    _refused(_two_joints("prismatic", limit), "a", "c", "'j2' is prismatic")
    _refused(_two_joints("floating"), "a", "c", "'floating'")
    _refused(_two_joints("revolute"), "a", "c", "no <limit")


def test_a_chain_without_moving_joints_is_refused():
    _refused(PANDA, "panda_link7", "panda_link8", "no moving joint")
    _refused(PANDA, "panda_link3", "panda_link3", "no moving joint")


def test_a_base_link_that_cannot_be_dh_frame_zero_is_refused():
    # the UR upper arm's frame has the elbow axis along its y axis, not z
    message = _refused(UR10, "upper_arm_link", "tool0", "cannot be DH frame 0")
    assert "elbow_joint" in message
    # joint 1 on the z axis but off the origin: a base offset, which a model does not carry
    off_axis = _two_joints(extra='<limit lower="-1" upper="1" effort="1" velocity="1"/>').replace(
        '<origin xyz="0 0 0.1"/>', '<origin xyz="0.05 0 0.1"/>'
    )
    _refused(off_axis, "a", "c", "cannot be DH frame 0")
    # joint 1 along -z: positive angles would turn the other way
    flipped = _two_joints(extra='<limit lower="-1" upper="1" effort="1" velocity="1"/>').replace(
        '<axis xyz="0 0 1"/>', '<axis xyz="0 0 -1"/>', 1
    )
    _refused(flipped, "a", "c", "cannot be DH frame 0")


def test_without_yourdfpy_the_extra_is_named(monkeypatch):
    monkeypatch.setitem(sys.modules, "yourdfpy", None)
    with pytest.raises(MissingExtraError, match=r"spacecal\[urdf\]"):
        robot_model_from_urdf(PANDA, "panda_link0", "panda_link8")


def test_the_models_import_without_yourdfpy():
    # the parser is imported when a URDF is read, not with the package
    code = "import sys, spacecal.models.urdf; sys.exit('yourdfpy' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", code], check=False).returncode == 0
