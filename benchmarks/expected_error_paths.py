"""The stated expected error against the measured error, on every path a recording takes.

For each scenario and seed one acquisition reaches ``spacecal calibrate --method ml`` by six
paths, and the calibration of each is verified in the same simulated world:

* **paired CSV**: the paired recording (joint angles, the tracker's fit RMS, the robot and
  marker in the metadata): the raw streams below paired on the robot's clock, as acquisition
  pairs them, through ``spacecal calibrate REC.csv``;
* **raw streams**: the robot's states and the tracker's frames on their own clocks, through
  ``spacecal calibrate STEM.robot.csv --tracker-stream STEM.tracker.csv`` (the clock offset
  estimated);
* **ROS 2 bag**: the raw streams recorded as a ROS user records them (the robot from ``/tf``,
  ``base -> flange`` and a static ``flange -> tcp``; the marker as a ``PoseStamped`` in the
  tracker frame) in a ROS 2 bag (sqlite3), then ``spacecal import-bag BAG -o STEM`` and
  calibrate as for raw streams, as the README shows: no joint angles, no fit RMS, no robot
  model or marker geometry;
* **TUM**: the raw streams as two TUM trajectories (metres, x,y,z,w quaternions), the robot's
  TCP poses and the tracker's seen marker poses, the tracker's clock :data:`TUM_CLOCK_GAP_S`
  behind the robot's, through ``spacecal import-poses`` and calibrate as for raw streams: no
  joint angles, no fit RMS;
* **pose-only**: the paired recording stripped to what a pose-only tracker sends
  (:meth:`~spacecal.records.Recording.as_pose_only`: no fit RMS, no sphere positions);
* **no joints**: the paired recording with its joint angles removed (robot metadata kept).

Measured: the mean position error at the needle tip over the paper's 15-point verification
around the site (§5.2, :func:`spacecal.experiments.verification.verify_in_simulation`, as
:mod:`benchmarks.accuracy` and :mod:`spacecal.experiments.prediction_oracle` measure it).
Stated: ``expected_error.position_mm``. The table gives, per scenario and
path, the median and the largest measured / stated over the seeds and their number (a refused
expected error is counted apart).

Scenarios: white noise (``paper-white``); realistic with a calibrated controller
(``paper-realistic``) and with a nominal-reporting one (``paper-realistic-nominal``);
``anisotropic`` (3x along the line of sight); a 30 ms clock offset (``paper-realistic``
with the robot's clock 30 ms ahead: the paired CSV, pose-only and no-joints paths then pair the
raw streams at the estimated offset, as :mod:`benchmarks.accuracy` does);
``camera-grade-pose-tracker``; ``static-15-poses`` (its raw, bag and TUM paths with the clock
offset given, :data:`OFFSET_GIVEN`). The named ones are the scenario files in
``src/spacecal/sim/data``. Named with ``--scenario``, the 15-pose set's two systematic errors
apart (:data:`PARTS`): its tracker field alone, its arm's residual alone.

    nice python benchmarks/expected_error_paths.py [--seeds 20] [--jobs 2] [--scenario NAME ...]
        [--path NAME ...] [--rows rows.csv] [--cache FOLDER]
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import pickle
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from spacecal.app.calibration import CalibrateSettings
from spacecal.app.calibration import calibrate as calibrate_files
from spacecal.app.poses import ImportPosesSettings, import_poses
from spacecal.app.ros import ImportBagSettings, import_bag
from spacecal.core.errors import SpacecalError
from spacecal.estimators import calibrate
from spacecal.estimators.time_offset import estimate_time_offset, pair_streams
from spacecal.experiments.simulation import simulate_raw
from spacecal.experiments.verification import verify_in_simulation
from spacecal.geometry.transforms import invert_transform, transform_to_position_quaternion
from spacecal.io.raw_streams import write_raw_recording
from spacecal.io.recording_csv import write_recording
from spacecal.io.tum import write_tum
from spacecal.records import CalibrationResult, RawRecording, Recording
from spacecal.sim.scenario import Scenario, load_scenario

#: label -> (scenario preset or file name, robot clock ahead of the tracker's, s)
SCENARIOS: dict[str, tuple[str, float]] = {
    "white noise": ("paper-white", 0.0),
    "realistic, calibrated controller": ("paper-realistic", 0.0),
    "realistic, nominal controller": ("paper-realistic-nominal", 0.0),
    "anisotropic": ("anisotropic", 0.0),
    "clock offset 30 ms": ("paper-realistic", 0.030),
    "camera-grade pose tracker": ("camera-grade-pose-tracker", 0.0),
    "15-pose static set": ("static-15-poses", 0.0),
}
#: The 15-pose set's two systematic errors apart, run only when named (``--scenario``): the
#: tracker's bias field without the arm's residual and repeatability, and the arm's without the
#: field. Each shows what the statement makes of one error family over so few poses.
PARTS = {
    "15-pose set, tracker field only": ("static-15-poses-field-only", 0.0),
    "15-pose set, arm residual only": ("static-15-poses-arm-only", 0.0),
}
#: Every scenario a case can name.
RUNNABLE = {**SCENARIOS, **PARTS}
PATHS = ("paired CSV", "raw streams", "ROS 2 bag", "TUM", "pose-only", "no joints")

#: Acquisitions taken at rest: their streams' angular speeds cannot fix the clock offset, so
#: ``spacecal calibrate`` refuses to guess it and asks for ``--time-offset-ms``; on the raw,
#: bag and TUM paths they are calibrated with it given, as that refusal asks.
OFFSET_GIVEN = ("15-pose static set", *PARTS)

#: The TUM path's tracker clock runs this far behind the robot's (s): minutes, as two devices'
#: own clocks are, found by the whole-overlap search.
TUM_CLOCK_GAP_S = 180.0

#: Header stamps of the bag start at a realistic ROS time (ns).
EPOCH_NS = 1_700_000_000 * 1_000_000_000


def write_ros2_bag(raw: RawRecording, folder: Path) -> Path:
    """The raw streams as a ROS 2 bag (sqlite3): ``/tf`` base -> flange at every robot state,
    ``/tf_static`` flange -> tcp, the marker's seen poses as ``PoseStamped`` on ``/tracker/marker``."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    types = store.types

    def header(stamp_ns: int, frame: str):
        time = types["builtin_interfaces/msg/Time"](sec=int(stamp_ns // 10**9), nanosec=int(stamp_ns % 10**9))
        return types["std_msgs/msg/Header"](stamp=time, frame_id=frame)

    def ros_parts(stack: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Translations (N, 3) in m and quaternions x, y, z, w (N, 4) with w >= 0, all at once."""
        positions, wxyz = transform_to_position_quaternion(stack)
        wxyz = np.where(wxyz[:, :1] < 0, -wxyz, wxyz)
        return positions / 1000.0, np.roll(wxyz, -1, axis=1)

    def tf(stamp_ns: int, parent: str, child: str, xyz: np.ndarray, q: np.ndarray):
        transform = types["geometry_msgs/msg/Transform"](
            translation=types["geometry_msgs/msg/Vector3"](x=xyz[0], y=xyz[1], z=xyz[2]),
            rotation=types["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
        )
        stamped = types["geometry_msgs/msg/TransformStamped"](
            header=header(stamp_ns, parent), child_frame_id=child, transform=transform
        )
        return types["tf2_msgs/msg/TFMessage"](transforms=[stamped])

    def pose(stamp_ns: int, xyz: np.ndarray, q: np.ndarray):
        message = types["geometry_msgs/msg/Pose"](
            position=types["geometry_msgs/msg/Point"](x=xyz[0], y=xyz[1], z=xyz[2]),
            orientation=types["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
        )
        return types["geometry_msgs/msg/PoseStamped"](header=header(stamp_ns, "tracker"), pose=message)

    flange_from_tcp = np.asarray(raw.metadata["robot"]["flange_from_tcp"], dtype=float)
    flange_xyz, flange_q = ros_parts(raw.base_from_tcp_stack @ invert_transform(flange_from_tcp))
    tool_xyz, tool_q = ros_parts(flange_from_tcp[None])
    robot_ns = EPOCH_NS + np.round(raw.robot_time_s * 1e9).astype(np.int64)
    tracker_ns = EPOCH_NS + np.round(raw.tracker_time_s * 1e9).astype(np.int64)
    seen = np.all(np.isfinite(raw.tracker_from_marker_stack[:, :3, 3]), axis=1)
    marker_xyz, marker_q = np.zeros((len(seen), 3)), np.zeros((len(seen), 4))
    marker_xyz[seen], marker_q[seen] = ros_parts(raw.tracker_from_marker_stack[seen])
    messages = [("/tf_static", "tf2_msgs/msg/TFMessage", int(robot_ns[0]), None, None)]
    messages += [("/tf", "tf2_msgs/msg/TFMessage", int(ns), "robot", k) for k, ns in enumerate(robot_ns)]
    messages += [
        ("/tracker/marker", "geometry_msgs/msg/PoseStamped", int(tracker_ns[k]), "marker", int(k))
        for k in np.flatnonzero(seen)
    ]
    messages.sort(key=lambda item: item[2])
    with Writer(folder, version=9, storage_plugin=StoragePlugin.SQLITE3) as writer:
        connections = {}
        for topic, msgtype, ns, kind, k in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
            if kind == "robot":
                message = tf(ns, "base", "flange", flange_xyz[k], flange_q[k])
            elif kind == "marker":
                message = pose(ns, marker_xyz[k], marker_q[k])
            else:
                message = tf(ns, "flange", "tcp", tool_xyz[0], tool_q[0])
            writer.write(connections[topic], ns, store.serialize_cdr(message, msgtype))
    return folder


def without_joints(recording: Recording) -> Recording:
    return dataclasses.replace(recording, joints_rad=np.full_like(recording.joints_rad, np.nan))


def scored(result: CalibrationResult, scenario: Scenario) -> tuple[float, float]:
    """(measured mean position error at the 15 targets, stated expected error), mm; the stated
    one NaN where the expected error was refused."""
    measured = verify_in_simulation(result, scenario).statistics()["position_mm"]["mean"]
    return float(measured), float(result.expected_error.to_dict().get("position_mm", np.nan))


def acquisition(label: str, seed: int, cache: str | None) -> tuple[Scenario, RawRecording, Recording]:
    """The scenario, its raw streams and its paired recording (simulated, or from ``cache``:
    the simulation costs most of a case, and does not change with the estimators)."""
    name, offset_s = RUNNABLE[label]
    scenario = dataclasses.replace(load_scenario(name), seed=seed)
    stored = None if cache is None else Path(cache) / f"{name}-{offset_s * 1000:g}ms-{seed}.pickle"
    if stored is not None and stored.exists():
        with open(stored, "rb") as file:
            raw, paired = pickle.load(file)
        return scenario, raw, paired
    raw, _ = simulate_raw(scenario, clock_offset_s=offset_s)
    # what acquisition pairs on the controller's clock, or (a clock offset) at the estimated one
    paired = pair_streams(raw, estimate_time_offset(raw).offset_s if offset_s else 0.0)
    if stored is not None:
        stored.parent.mkdir(parents=True, exist_ok=True)
        with open(stored, "wb") as file:
            pickle.dump((raw, paired), file)
    return scenario, raw, paired


def run_case(case: tuple[str, int, tuple[str, ...], str | None]) -> list[tuple[str, str, int, float, float]]:
    """Rows (scenario, path, seed, measured mm, stated mm) of one scenario and seed."""
    label, seed, paths, cache = case
    scenario, raw, paired = acquisition(label, seed, cache)
    rows = []
    with tempfile.TemporaryDirectory() as temporary:
        folder = Path(temporary)

        robot_ahead_s = RUNNABLE[label][1]

        def from_files(
            recording: str | Path, tracker_stream: str | Path | None = None, tracker_behind_s: float = 0.0
        ) -> CalibrationResult:
            given = label in OFFSET_GIVEN and tracker_stream is not None
            settings = CalibrateSettings(
                str(recording),
                str(folder / "cal.json"),
                method="ml",
                tracker_stream=None if tracker_stream is None else str(tracker_stream),
                time_offset_ms=1000.0 * (robot_ahead_s + tracker_behind_s) if given else None,
                force=True,
            )
            return calibrate_files(settings).record

        for path in paths:
            try:
                if path == "paired CSV":
                    result = from_files(write_recording(paired, folder / "rec.csv"))
                elif path == "raw streams":
                    robot, tracker = write_raw_recording(raw, folder / "raw")
                    result = from_files(robot, tracker)
                elif path == "ROS 2 bag":
                    bag = write_ros2_bag(raw, folder / "bag")
                    import_bag(ImportBagSettings(str(bag), output=str(folder / "imported"), force=True))
                    result = from_files(folder / "imported.robot.csv", folder / "imported.tracker.csv")
                elif path == "TUM":
                    seen = np.all(np.isfinite(raw.tracker_from_marker_stack[:, :3, 3]), axis=1)
                    write_tum(folder / "robot.tum", raw.robot_time_s, raw.base_from_tcp_stack)
                    write_tum(
                        folder / "tracker.tum",
                        raw.tracker_time_s[seen] - TUM_CLOCK_GAP_S,
                        raw.tracker_from_marker_stack[seen],
                    )
                    import_poses(
                        ImportPosesSettings(
                            str(folder / "robot.tum"),
                            str(folder / "tracker.tum"),
                            output=str(folder / "tum"),
                            force=True,
                        )
                    )
                    result = from_files(folder / "tum.robot.csv", folder / "tum.tracker.csv", TUM_CLOCK_GAP_S)
                elif path == "pose-only":
                    result = calibrate(paired.as_pose_only(), "ml")
                else:
                    result = calibrate(without_joints(paired), "ml")
                measured, stated = scored(result, scenario)
            except SpacecalError as exc:
                print(f"{label}, seed {seed}, {path}: {exc}", file=sys.stderr)
                measured, stated = np.nan, np.nan
            rows.append((label, path, seed, measured, stated))
    return rows


def table(rows: list[tuple[str, str, int, float, float]], scenarios: list[str], paths: list[str]) -> None:
    print(
        "| scenario | path | n | median measured / stated | max measured / stated | "
        "median stated (mm) | median measured (mm) |"
    )
    print("|---|---|---|---|---|---|---|")
    for label in scenarios:
        for path in paths:
            values = np.array([(r[3], r[4]) for r in rows if r[0] == label and r[1] == path], dtype=float)
            if len(values) == 0:
                continue
            stated_ok = np.isfinite(values[:, 1]) & (values[:, 1] > 0)
            ratio = values[stated_ok, 0] / values[stated_ok, 1]
            refused = int(np.sum(~stated_ok))
            n = f"{len(ratio)}" + (f" (+{refused} refused)" if refused else "")
            if len(ratio) == 0:
                print(f"| {label} | {path} | {n} | – | – | – | – |")
                continue
            print(
                f"| {label} | {path} | {n} | {np.median(ratio):.2f} | {ratio.max():.2f} | "
                f"{np.median(values[stated_ok, 1]):.3f} | {np.median(values[stated_ok, 0]):.3f} |"
            )


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--first-seed", type=int, default=1)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument(
        "--scenario", action="append", choices=list(RUNNABLE), help="default: all but the 15-pose parts"
    )
    parser.add_argument("--path", action="append", choices=list(PATHS), help="default: all")
    parser.add_argument("--rows", help="also write every run (scenario, path, seed, measured, stated) here")
    parser.add_argument("--cache", help="keep the simulated acquisitions in this folder and reuse them")
    args = parser.parse_args()
    scenarios = args.scenario or list(SCENARIOS)
    paths = tuple(args.path or PATHS)
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    cases = [(label, seed, paths, args.cache) for label in scenarios for seed in seeds]
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        rows = [row for case_rows in pool.map(run_case, cases) for row in case_rows]
    if args.rows:
        with open(args.rows, "w", newline="", encoding="utf-8") as file:
            writer = csv.writer(file)
            writer.writerow(["scenario", "path", "seed", "measured_mm", "stated_mm"])
            writer.writerows(rows)
    print(
        f"Measured / stated expected error at the verification targets, ml, seeds "
        f"{seeds.start}-{seeds.stop - 1}\n"
    )
    table(rows, scenarios, list(paths))


if __name__ == "__main__":
    main()
