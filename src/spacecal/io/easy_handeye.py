"""easy_handeye (ROS 1) and easy_handeye2 (ROS 2) result and sample files.

What easy_handeye stores, read from its source (``easy_handeye2``: ``handeye_sampler.py``,
``handeye_calibration_backend_opencv.py``, ``handeye_publisher.py``; ``easy_handeye``:
``handeye_calibration.py``):

* **Result, eye-on-base** (tracker fixed in the world, marker on the robot — spacecal's set-up):
  the transform from ``robot_base_frame`` (tf parent) to ``tracking_base_frame`` (tf child), i.e.
  the pose of the tracker in the robot base = our ``base_from_tracker``
  (= ``invert(tracker_from_base)``). The publisher broadcasts it with
  ``header.frame_id = robot_base_frame`` and ``child_frame_id = tracking_base_frame``.
  For eye-in-hand it is ``robot_effector_frame -> tracking_base_frame`` instead.
* **Samples**: each holds ``robot`` and ``tracking``, both ``geometry_msgs/Transform`` looked up in
  tf as ``lookup_transform(target, source)`` = ``target_from_source``. ``tracking`` is
  ``tracking_base_frame <- tracking_marker_frame`` = ``tracker_from_marker``. ``robot`` is, for
  eye-on-base, ``lookup_transform(robot_effector_frame, robot_base_frame)`` =
  ``effector_from_base`` (the inverted robot pose that makes OpenCV's eye-in-hand solver return
  ``base_from_tracker``); for eye-in-hand it is ``base_from_effector``.

File layouts:

* easy_handeye2 ``.calib`` (``rosidl_runtime_py.message_to_yaml`` of a ``HandeyeCalibration``
  message): ``parameters`` (name, calibration_type ``eye_on_base``/``eye_in_hand``,
  robot_base_frame, robot_effector_frame, tracking_base_frame, tracking_marker_frame,
  freehand_robot_movement, move_group_namespace, move_group) and ``transform`` (``translation``
  x, y, z in metres; ``rotation`` x, y, z, w).
* easy_handeye2 ``.samples`` (a ``SampleList`` message): ``parameters`` as above and
  ``samples``, a list of ``{robot: Transform, tracking: Transform}``.
* easy_handeye (ROS 1) ``.yaml``: either ``parameters`` (with ``eye_on_hand`` true/false and the
  frames) or, in older releases, the flat keys ``eye_on_hand``, ``robot_base_frame`` or
  ``robot_effector_frame``, ``tracking_base_frame``; and ``transformation`` with ``x, y, z, qx,
  qy, qz, qw`` (metres). Still older files name the frames ``base_link_frame`` / ``tool_frame``
  / ``optical_origin_frame``; they are read too.

Boundary conversions: metres -> mm, quaternion ``x, y, z, w`` -> rotation matrix. The robot
effector frame of the samples is spacecal's ``tcp`` (whatever frame easy_handeye was told).
Reading needs PyYAML (``spacecal[ros]``); writing does not.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spacecal.core.errors import InvalidInputError
from spacecal.core.text import quoted
from spacecal.geometry.transforms import invert_transform
from spacecal.io.atomic import write_text_atomic
from spacecal.io.names import check_calibration_name, check_ros_frame_name
from spacecal.io.ros_common import (
    MAX_QUATERNION_COMPONENT,
    MAX_TRANSLATION_M,
    field,
    number_field,
    transform_from_ros,
    transform_to_ros,
)
from spacecal.io.yaml_text import load_yaml_mapping, yaml_comment, yaml_number, yaml_string
from spacecal.records import Recording

CALIBRATION_TYPES = ("eye_on_base", "eye_in_hand")


@dataclass(frozen=True)
class HandEyeCalibration:
    """A hand-eye result as easy_handeye stores it.

    Attributes
    ----------
    calibration_type : str
        ``"eye_on_base"`` or ``"eye_in_hand"``.
    robot_base_frame, robot_effector_frame, tracking_base_frame, tracking_marker_frame : str
        The ROS frame names (empty where the file does not give one).
    parent_from_child : numpy.ndarray, shape (4, 4)
        The stored transform, mm: ``robot_base_frame <- tracking_base_frame`` for eye-on-base
        (our ``base_from_tracker``), ``robot_effector_frame <- tracking_base_frame`` for eye-in-hand.
    name : str
        The calibration's name (easy_handeye2) or namespace (easy_handeye).
    source : str
        ``"easy_handeye2"`` or ``"easy_handeye"``.
    """

    calibration_type: str
    robot_base_frame: str
    robot_effector_frame: str
    tracking_base_frame: str
    tracking_marker_frame: str
    parent_from_child: np.ndarray
    name: str = ""
    source: str = "easy_handeye2"

    @property
    def parent_frame(self) -> str:
        """The tf parent of the stored transform."""
        return self.robot_base_frame if self.calibration_type == "eye_on_base" else self.robot_effector_frame

    @property
    def child_frame(self) -> str:
        """The tf child of the stored transform (the tracker / camera frame)."""
        return self.tracking_base_frame

    @property
    def tracker_from_base(self) -> np.ndarray:
        """spacecal's calibration (4, 4), mm; only for eye-on-base results."""
        if self.calibration_type != "eye_on_base":
            raise InvalidInputError(
                f"{quoted(self.name) if self.name else 'calibration'}: an {self.calibration_type} result "
                "has no tracker_from_base "
                "(spacecal calibrates a fixed tracker: eye_on_base)"
            )
        return invert_transform(self.parent_from_child)


def _transform_message(message, where: str) -> np.ndarray:
    """``geometry_msgs/Transform`` as parsed YAML -> 4x4 mm."""
    translation = field(message, "translation", where)
    rotation = field(message, "rotation", where)
    xyz = [number_field(translation, k, f"{where}.translation", MAX_TRANSLATION_M) for k in ("x", "y", "z")]
    xyzw = [
        number_field(rotation, k, f"{where}.rotation", MAX_QUATERNION_COMPONENT) for k in ("x", "y", "z", "w")
    ]
    return transform_from_ros(xyz, xyzw, where)


def _frame(mapping: dict, *keys: str) -> str:
    for key in keys:
        value = mapping.get(key)
        if isinstance(value, str) and value:
            return value.lstrip("/")
    return ""


def _parameters2(parameters, where: str) -> dict:
    if not isinstance(parameters, dict):
        raise InvalidInputError(f"{where}: 'parameters' is not a mapping")
    kind = field(parameters, "calibration_type", where)
    if kind not in CALIBRATION_TYPES:
        raise InvalidInputError(
            f"{where}: calibration_type {quoted(kind)}, expected one of {', '.join(CALIBRATION_TYPES)}"
        )
    return {
        "calibration_type": kind,
        "robot_base_frame": _frame(parameters, "robot_base_frame"),
        "robot_effector_frame": _frame(parameters, "robot_effector_frame"),
        "tracking_base_frame": _frame(parameters, "tracking_base_frame"),
        "tracking_marker_frame": _frame(parameters, "tracking_marker_frame"),
        "name": str(parameters.get("name", "") or ""),
    }


def _parameters1(data: dict, where: str) -> dict:
    block = data["parameters"] if isinstance(data.get("parameters"), dict) else data
    if "eye_on_hand" not in block:
        raise InvalidInputError(f"{where}: missing field 'eye_on_hand'")
    eye_on_hand = block["eye_on_hand"]
    if not isinstance(eye_on_hand, bool):
        raise InvalidInputError(f"{where}: eye_on_hand is {quoted(eye_on_hand)}, expected true or false")
    return {
        "calibration_type": "eye_in_hand" if eye_on_hand else "eye_on_base",
        "robot_base_frame": _frame(block, "robot_base_frame", "base_link_frame"),
        "robot_effector_frame": _frame(block, "robot_effector_frame", "tool_frame"),
        "tracking_base_frame": _frame(block, "tracking_base_frame", "optical_origin_frame"),
        "tracking_marker_frame": _frame(block, "tracking_marker_frame"),
        "name": str(block.get("namespace", "") or "").strip("/"),
    }


def read_easy_handeye_calibration(path: str | Path) -> HandEyeCalibration:
    """Read an easy_handeye2 ``.calib`` or an easy_handeye (ROS 1) ``.yaml`` result.

    Returns
    -------
    HandEyeCalibration
        ``.tracker_from_base`` gives spacecal's calibration for an eye-on-base result.

    Raises
    ------
    InvalidInputError
        A file that is neither layout, a missing field, a non-unit quaternion.
    """
    path = Path(path)
    data = load_yaml_mapping(path, "easy_handeye calibration")
    where = str(path)
    if "transform" in data:
        parameters = _parameters2(field(data, "parameters", where), f"{where}: parameters")
        matrix = _transform_message(data["transform"], f"{where}: transform")
        source = "easy_handeye2"
    elif "transformation" in data:
        parameters = _parameters1(data, where)
        block = data["transformation"]
        tw = f"{where}: transformation"
        xyz = [number_field(block, k, tw, MAX_TRANSLATION_M) for k in ("x", "y", "z")]
        xyzw = [number_field(block, k, tw, MAX_QUATERNION_COMPONENT) for k in ("qx", "qy", "qz", "qw")]
        matrix = transform_from_ros(xyz, xyzw, tw)
        source = "easy_handeye"
    else:
        raise InvalidInputError(
            f"{where}: neither an easy_handeye2 .calib ('parameters' + 'transform') nor an easy_handeye "
            "result ('transformation')"
        )
    return HandEyeCalibration(parent_from_child=matrix, source=source, **parameters)


def _transform_yaml(matrix: np.ndarray, indent: str) -> list[str]:
    translation_m, quaternion_xyzw = transform_to_ros(matrix)
    lines = [f"{indent}translation:"]
    lines += [f"{indent}  {k}: {yaml_number(v)}" for k, v in zip("xyz", translation_m)]
    lines += [f"{indent}rotation:"]
    lines += [f"{indent}  {k}: {yaml_number(v)}" for k, v in zip("xyzw", quaternion_xyzw)]
    return lines


#: The frame parameters of an easy_handeye2 file, in its order.
FRAME_PARAMETERS = (
    "robot_base_frame",
    "robot_effector_frame",
    "tracking_base_frame",
    "tracking_marker_frame",
)


def _checked_parameters(name: str, frames: dict[str, str]) -> dict[str, str]:
    """The name and the four frames (``FRAME_PARAMETERS`` keys), each checked: a portable
    calibration name, ROS frame names. Raises before anything is written."""
    checked = {"name": check_calibration_name(name, "easy_handeye2 calibration name")}
    for key in FRAME_PARAMETERS:
        checked[key] = check_ros_frame_name(frames[key], f"easy_handeye2 {key}")
    return checked


def _parameters_yaml(parameters: dict, calibration_type: str) -> list[str]:
    return [
        "parameters:",
        f"  name: {yaml_string(parameters['name'])}",
        f"  calibration_type: {yaml_string(calibration_type)}",
        *(f"  {key}: {yaml_string(parameters[key])}" for key in FRAME_PARAMETERS),
        "  freehand_robot_movement: true",
        "  move_group_namespace: /",
        "  move_group: manipulator",
    ]


def easy_handeye2_calibration_text(
    tracker_from_base,
    *,
    name: str,
    robot_base_frame: str,
    robot_effector_frame: str,
    tracking_base_frame: str,
    tracking_marker_frame: str,
) -> str:
    """spacecal's calibration as an easy_handeye2 eye-on-base ``.calib`` file (YAML text).

    Parameters
    ----------
    tracker_from_base : array_like, shape (4, 4)
        The calibration, mm. The file stores its inverse, ``base_from_tracker`` (the pose of
        ``tracking_base_frame`` in ``robot_base_frame``), in metres with a quaternion x, y, z, w,
        which is what easy_handeye2's publisher broadcasts from ``robot_base_frame`` to
        ``tracking_base_frame``.
    name : str
        The calibration name; easy_handeye2 loads ``~/.ros2/easy_handeye2/calibrations/<name>.calib``.
    robot_base_frame, robot_effector_frame, tracking_base_frame, tracking_marker_frame : str
        ROS frame names: spacecal's base, tcp, tracker and marker frames as named in your tf tree.
    """
    parameters = _checked_parameters(
        name,
        {
            "robot_base_frame": robot_base_frame,
            "robot_effector_frame": robot_effector_frame,
            "tracking_base_frame": tracking_base_frame,
            "tracking_marker_frame": tracking_marker_frame,
        },
    )
    base_from_tracker = invert_transform(np.asarray(tracker_from_base, dtype=float))
    lines = [
        "# easy_handeye2 HandeyeCalibration written by spacecal (eye_on_base).",
        yaml_comment(
            f"transform = pose of {tracking_base_frame} in {robot_base_frame} "
            f"({robot_base_frame} -> {tracking_base_frame}, spacecal's base_from_tracker),"
        ),
        "# metres, quaternion x y z w.",
    ]
    lines += _parameters_yaml(parameters, "eye_on_base")
    lines += ["transform:"] + _transform_yaml(base_from_tracker, "  ")
    return "\n".join(lines) + "\n"


def write_easy_handeye2_calibration(path: str | Path, tracker_from_base, **frames) -> Path:
    """Write :func:`easy_handeye2_calibration_text` to ``path`` (conventionally ``<name>.calib``).

    Keyword arguments are those of :func:`easy_handeye2_calibration_text`; ``name`` defaults to
    the file's stem.
    """
    path = Path(path)
    frames.setdefault("name", path.stem)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(easy_handeye2_calibration_text(tracker_from_base, **frames), path)
    return path


def read_easy_handeye_samples(path: str | Path) -> Recording:
    """Read easy_handeye2 or easy_handeye sample lists into a :class:`Recording`.

    Two layouts are read:

    * easy_handeye2's ``.samples`` file (a ``SampleList`` with ``parameters`` and
      ``samples: [{robot, tracking}]``);
    * easy_handeye's (ROS 1) ``SampleList`` as YAML, e.g. saved from its
      ``get_sample_list`` service (``rosservice call /easy_handeye_eye_on_base/get_sample_list
      > samples.yaml``): ``hand_world_samples`` and ``camera_marker_samples``, each a list of
      ``geometry_msgs/Transform`` (or a ``TransformArray`` with ``transforms``), possibly under
      ``samples``. It carries no parameters; eye-on-base is assumed (its sampler's robot
      transform is then ``effector_from_base``, as in easy_handeye2).

    Each sample becomes one row: ``base_from_tcp`` is the inverse of the stored robot
    transform (``effector_from_base`` for eye-on-base), ``tracker_from_marker`` the stored
    tracking transform. The samples carry no times or joint angles: ``time_s`` is the sample
    index (s), ``joints_rad`` and ``marker_rms_mm`` are NaN, ``segment`` is ``"sample"``.

    Raises
    ------
    InvalidInputError
        An eye-in-hand sample list (the tracker moves with the robot: not spacecal's set-up),
        fewer than 3 samples, a missing field, a non-unit quaternion.
    """
    path = Path(path)
    data = load_yaml_mapping(path, "easy_handeye sample list")
    where = str(path)
    ros1 = _ros1_sample_list(data)
    if ros1 is not None:
        robot_messages, tracking_messages = ros1
        parameters = {
            "robot_base_frame": "base",
            "robot_effector_frame": "tool",
            "tracking_base_frame": "tracker",
            "tracking_marker_frame": "marker",
        }
    else:
        parameters = _parameters2(field(data, "parameters", where), f"{where}: parameters")
        if parameters["calibration_type"] != "eye_on_base":
            raise InvalidInputError(
                f"{where}: calibration_type is {parameters['calibration_type']}; spacecal re-solves "
                "eye_on_base samples (tracker fixed, marker on the robot)"
            )
        samples = field(data, "samples", where)
        if not isinstance(samples, list):
            raise InvalidInputError(f"{where}: 'samples' must be a list")
        robot_messages = [field(s, "robot", f"{where}: sample {k}") for k, s in enumerate(samples)]
        tracking_messages = [field(s, "tracking", f"{where}: sample {k}") for k, s in enumerate(samples)]
    if len(robot_messages) < 3 or len(robot_messages) != len(tracking_messages):
        raise InvalidInputError(
            f"{where}: {len(robot_messages)} robot and {len(tracking_messages)} tracking samples; "
            "at least 3 pairs are needed"
        )
    effector_from_base = np.array(
        [_transform_message(m, f"{where}: sample {k}.robot") for k, m in enumerate(robot_messages)]
    )
    tracker_from_marker = np.array(
        [_transform_message(m, f"{where}: sample {k}.tracking") for k, m in enumerate(tracking_messages)]
    )
    samples = robot_messages
    count = len(samples)
    return Recording(
        time_s=np.arange(count, dtype=float),
        segment=np.array(["sample"] * count),
        joints_rad=np.full((count, 6), np.nan),
        base_from_tcp_stack=invert_transform(effector_from_base),
        tracker_from_marker_stack=tracker_from_marker,
        marker_rms_mm=np.full(count, np.nan),
        metadata={
            "source": "easy_handeye samples (ROS 1)" if ros1 is not None else "easy_handeye2 samples",
            "file": str(path),
            "frames": {
                "base": parameters["robot_base_frame"],
                "tcp": parameters["robot_effector_frame"],
                "tracker": parameters["tracking_base_frame"],
                "marker": parameters["tracking_marker_frame"],
            },
            "units": {"length": "mm", "angle": "rad", "time": "s (sample index)"},
        },
    )


def easy_handeye2_samples_text(
    base_from_tcp_stack,
    tracker_from_marker_stack,
    *,
    name: str,
    robot_base_frame: str,
    robot_effector_frame: str,
    tracking_base_frame: str,
    tracking_marker_frame: str,
) -> str:
    """Poses (N, 4, 4), mm, as an easy_handeye2 eye-on-base ``.samples`` file, so easy_handeye2 can
    load and solve spacecal's recordings. The ``robot`` transform is written as ``effector_from_base``
    (the inverse of ``base_from_tcp``), as its sampler stores it for eye-on-base."""
    base_from_tcp_stack = np.asarray(base_from_tcp_stack, dtype=float)
    tracker_from_marker_stack = np.asarray(tracker_from_marker_stack, dtype=float)
    if base_from_tcp_stack.shape != tracker_from_marker_stack.shape or base_from_tcp_stack.ndim != 3:
        raise InvalidInputError("easy_handeye2 samples: expected two pose stacks of equal shape (N, 4, 4)")
    parameters = _checked_parameters(
        name,
        {
            "robot_base_frame": robot_base_frame,
            "robot_effector_frame": robot_effector_frame,
            "tracking_base_frame": tracking_base_frame,
            "tracking_marker_frame": tracking_marker_frame,
        },
    )
    seen = np.all(np.isfinite(tracker_from_marker_stack.reshape(len(tracker_from_marker_stack), -1)), axis=1)
    lines = _parameters_yaml(parameters, "eye_on_base")
    lines.append("samples:")
    for base_from_tcp, tracker_from_marker in zip(base_from_tcp_stack[seen], tracker_from_marker_stack[seen]):
        robot = _transform_yaml(invert_transform(base_from_tcp), "    ")
        lines += ["- robot:"] + robot
        lines += ["  tracking:"] + _transform_yaml(tracker_from_marker, "    ")
    return "\n".join(lines) + "\n"


def _ros1_sample_list(data: dict) -> tuple[list, list] | None:
    """easy_handeye (ROS 1) ``SampleList`` content, or None for another layout."""
    body = data.get("samples", data)
    if not isinstance(body, dict) or "hand_world_samples" not in body:
        return None

    def transforms(value: object) -> list:
        if isinstance(value, dict) and "transforms" in value:  # visp TransformArray
            value = value["transforms"]
        if not isinstance(value, list):
            raise InvalidInputError("easy_handeye sample list: samples must be lists of transforms")
        return value

    return transforms(body["hand_world_samples"]), transforms(body.get("camera_marker_samples"))
