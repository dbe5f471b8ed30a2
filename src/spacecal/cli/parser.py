"""The argument parser of ``spacecal``; every default is read from the app's settings."""

from __future__ import annotations

import argparse
import dataclasses
import inspect
import math
import re
from typing import Any, NoReturn

from spacecal import __version__, app
from spacecal.core.strict_numbers import decimal, integer, parse_int

#: Options whose values are coordinates, often negative (base-frame positions).
COORDINATE_OPTIONS = ("--target", "--workspace-box", "--tool-offset-mm", "--tool")


def port_number(text: str) -> int:
    """A TCP port 0..65535, 0 meaning any free one (argparse turns the ValueError into a usage error)."""
    value = parse_int(text)
    if not 0 <= value <= 65535:
        raise ValueError(text)
    return value


def settings_classes(name: str) -> list[type]:
    """The settings classes the app function of command ``name`` takes, read from its signature."""
    function = app.COMMANDS.get(name)
    hints = (
        [] if function is None else [p.annotation for p in inspect.signature(function).parameters.values()]
    )
    names = [getattr(hint, "__name__", hint) for hint in hints]  # a class, or its name as written
    return [getattr(app, n) for n in names if isinstance(n, str) and n.endswith("Settings")]


def defaults_of(*classes: type) -> dict[str, Any]:
    """The default of each field of settings ``classes``, by name; a nested settings field (the
    devices) gives its own fields' defaults."""
    found: dict[str, Any] = {}
    for cls in classes:
        for f in dataclasses.fields(cls):
            if f.default is not dataclasses.MISSING:
                found[f.name] = f.default
            elif f.default_factory is not dataclasses.MISSING:
                value = f.default_factory()
                nested = dataclasses.is_dataclass(value) and not isinstance(value, type)
                found.update(vars(value) if nested else {f.name: value})
    # an option given again and again (--target, --rom) appends to None, not to an empty tuple
    return {name: None if value == () else value for name, value in found.items()}


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line (the usage block is on ``--help``);
    the exit code stays argparse's 2 for a command line that does not parse."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {' '.join(message.split())} (see {self.prog} --help)\n")


def build_parser(commands_impl: dict) -> argparse.ArgumentParser:
    """The parser; ``commands_impl`` maps each command name to the function that runs it."""
    parser = OneLineParser(
        prog="spacecal", description="Calibrate a surgical robot's base frame to an optical tracker."
    )
    parser.add_argument("--version", action="version", version=f"spacecal {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    scenario_help = f"scenario JSON file or preset (default {app.DEFAULT_SCENARIO})"

    def command(name: str, help_text: str) -> argparse.ArgumentParser:
        p = sub.add_parser(name, help=help_text)
        # every option's default is its settings field's: set before the options are added
        classes = settings_classes(name)
        p.set_defaults(run=commands_impl[name], **defaults_of(*classes))
        flags = {**SHARED_FLAGS, **{k: v for c in classes for k, v in getattr(c, "FLAGS", {}).items()}}
        for field in dict.fromkeys(f.name for c in classes for f in dataclasses.fields(c)):
            if field in flags:  # flags several commands share, and those a command's settings declare
                flag, options = flags[field]
                p.add_argument(*flag.split(), **options)
        return p

    p = command("simulate", "simulate a calibration run on the simulated system -> recording CSV")
    p.add_argument("--scenario", help=scenario_help)
    p.add_argument("--seed", type=integer, help="override the scenario's seed")
    p.add_argument(
        "--raw", action="store_true", help="write the raw streams (STEM.robot.csv, STEM.tracker.csv)"
    )
    p.add_argument("--clock-offset-ms", type=decimal, help="with --raw: robot clock ahead of the tracker's")
    p.add_argument("--plan", help="a plan file (spacecal plan -o) to run instead of the paper's sweeps")
    p.add_argument("-o", "--output", required=True, help="recording CSV to write (with --raw: the stem)")

    p = command("calibrate", "estimate tracker_from_base from a recording")
    p.add_argument("recording", help="recording CSV (or, with --tracker-stream, the robot stream)")
    p.add_argument("--method", help=f"estimator: {', '.join(app.ESTIMATOR_NAMES)}")
    p.add_argument("--tracker-stream", help="the raw tracker stream: pair it with the robot stream first")
    p.add_argument(
        "--include-doubtful-frames",
        action="store_true",
        help="also use poses the tracker flagged (e.g. partially out of volume); left out by default",
    )
    p.add_argument(
        "--time-offset-ms",
        default="estimate",
        help="with --tracker-stream: robot clock minus tracker clock in ms, any size (the clocks may "
        "count from unrelated epochs), or 'estimate' (default: searched over every offset at which "
        "the streams overlap)",
    )
    p.add_argument("-o", "--output", required=True, help="calibration JSON to write")
    p.add_argument(
        "--target",
        action="append",
        dest="targets_in_base",
        metavar="X,Y,Z",
        help="point in the base frame (mm) to predict the TRE at; repeatable",
    )
    p.add_argument(
        "--sigma-mm", type=decimal, help="per-axis sphere noise (ml, robust); default: from marker_rms_mm"
    )
    add_thresholds(p)
    p.add_argument(
        "--tracker-kind",
        choices=app.TRACKER_KINDS,
        help="spheres (optical tracker with fit RMS), pose (poses only: a camera, PLUS); default: "
        "auto, from what the recording holds",
    )
    p.add_argument("--tip", metavar="PIVOT.json", help="the needle's pivot (spacecal pivot -o): IK aims it")

    p = command("pivot", "pivot calibration of a pointer or needle tip")
    p.add_argument("poses", help="folder of 4x4 .txt pose files, or a recording CSV")
    p.add_argument("--method", help="aos (algebraic one-step) or sphere")
    p.add_argument("--subset", help="file listing the pose file names to use")
    p.add_argument("-o", "--output", help="pivot result JSON to write")

    p = command("bound", "Cramer-Rao lower bound on TRE for a recording")
    p.add_argument("recording", help="recording CSV")
    p.add_argument("--calibration", required=True, help="calibration JSON (where to evaluate the bound)")
    p.add_argument(
        "--sigma-mm",
        type=decimal,
        help="per-axis sphere noise, mm; default: from the recording's tracker fit RMS, else the "
        "calibration's noise, else learnt from its residuals (the line printed says which)",
    )
    p.add_argument(
        "--target",
        action="append",
        dest="targets_in_base",
        metavar="X,Y,Z",
        help="point in the base frame (mm); repeatable",
    )

    p = command("verify", "the paper's verification experiment: on the robot (--robot), or in simulation")
    add_devices(p, simulated_by_default=False)
    p.add_argument("calibration", help="calibration JSON")
    p.add_argument("--scenario", help="simulated world (default: the one the calibration's data came from)")
    p.add_argument("-o", "--output", help="verification JSON to write")
    p.add_argument("--figure", help="PNG of the error curves (paper Fig. 7)")

    p = command("demo", "simulate, calibrate and verify; print a summary table")
    p.add_argument("--scenario", help=scenario_help)
    p.add_argument("--out", help="directory to write the recording, calibration, verification and figure to")

    p = command("acquire", "run the calibration motion on a robot while sampling the tracker")
    add_devices(p)
    p.add_argument("--scenario", help="scenario of the simulated devices")
    p.add_argument("-o", "--output", required=True, help="recording CSV to write (each sample flushed)")
    p.add_argument("--dry-run", action="store_true", help="check the plan without moving")
    p.add_argument("--plan", help="a plan file (spacecal plan -o) to run; the robot must stand at its home")
    p.add_argument(
        "--stop-and-go",
        type=integer,
        metavar="N",
        help="stop at stations along each move, average N frames at each (default 0: sample while moving)",
    )
    p.add_argument("--resume", action="store_true", help="continue a stopped acquisition of the same plan")
    p.add_argument("--speed-mm-s", type=decimal, help="TCP speed")
    p.add_argument("--accel-mm-s2", type=decimal, help="TCP acceleration")
    p.add_argument("--angular-speed-deg-s", type=decimal, help="TCP rotation speed")
    p.add_argument("--prior", help="an earlier calibration, to check marker visibility along the plan")
    p.add_argument("--rotation-deg", type=decimal, help="rotation sweep each way")
    p.add_argument("--translation-mm", type=decimal, help="translation sweep stroke")
    p.add_argument(
        "--live-view",
        nargs="?",
        type=port_number,
        const=app.LIVE_VIEW_PORT,
        metavar="PORT",
        help=f"show the marker, the sweeps and the samples in a web browser at http://127.0.0.1:PORT/ "
        f"(default port {app.LIVE_VIEW_PORT}) while the motion runs",
    )

    p = command(
        "register-landmarks",
        "register a phantom to its reference marker from a tracked-stylus PLUS recording",
    )
    p.add_argument(
        "sequence", help="PLUS sequence file (.igs.mha) with <Reference>ToTracker and <Stylus>ToTracker"
    )
    p.add_argument(
        "--config", required=True, help="PLUS device set: StylusTip->Stylus transform and <Landmarks>"
    )
    p.add_argument("--reference", help="reference tool name")
    p.add_argument("--stylus", help="stylus tool name")
    p.add_argument(
        "--plus-compatible", action="store_true", help="average landmark frames exactly as PLUS does"
    )
    p.add_argument("-o", "--output", help="registration JSON to write")

    p = command("export", "export a calibration to 3D Slicer, PLUS, or over OpenIGTLink")
    p.add_argument("calibration", help="calibration JSON")
    p.add_argument("--slicer", help="ITK transform file (.tfm) for 3D Slicer")
    p.add_argument("--plus", help="PLUS CoordinateDefinitions XML")
    p.add_argument(
        "--igtl", metavar="HOST:PORT", help="send BaseToTracker to an OpenIGTLink server (e.g. Slicer)"
    )
    p.add_argument("--easy-handeye2", metavar="FILE.calib", help="easy_handeye2 eye-on-base result file")
    p.add_argument(
        "--ros2-launch", metavar="FILE.launch.py", help="ROS 2 launch file publishing the static transform"
    )
    p.add_argument(
        "--urdf", metavar="FILE.urdf", help="URDF snippet: a fixed joint from the base link to the tracker"
    )
    p.add_argument("--static-tf", action="store_true", help="print a ros2 static_transform_publisher command")
    p.add_argument(
        "--ur-calibration",
        metavar="FILE.yaml",
        help="UR ROS driver kinematics file of the identified robot model (--method kinematic)",
    )
    for name, what in (
        ("base", "robot base link (tf parent)"),
        ("tool", "robot tool flange"),
        ("tracker", "tracker (tf child)"),
        ("marker", "marker"),
    ):
        p.add_argument(f"--{name}-frame", help=f"ROS frame of the {what}")

    p = command("import-plus", "turn a PLUS sequence file (.igs.mha) into a recording CSV")
    p.add_argument("sequence", help="PLUS sequence file")
    p.add_argument("--marker", help="marker transform name")
    p.add_argument("--tcp", help="robot TCP transform name")
    p.add_argument("--segment", help="segment label for every frame")
    p.add_argument("-o", "--output", required=True, help="recording CSV to write")

    p = command("import-bag", "turn a ROS 1 or ROS 2 bag into a raw two-stream recording (spacecal[ros])")
    p.add_argument("bag", help="ROS 1 .bag, ROS 2 bag folder, or a .db3 / .mcap file")
    p.add_argument("-o", "--output", help="stem of STEM.robot.csv and STEM.tracker.csv")
    p.add_argument(
        "--list",
        action="store_true",
        dest="list_only",
        help="show the topics and tf frames found, write nothing",
    )
    p.add_argument("--base-frame", help="tf: robot base frame")
    p.add_argument("--tool-frame", help="tf: robot tool (TCP) frame")
    p.add_argument("--tracker-frame", help="tf: tracker frame")
    p.add_argument("--marker-frame", help="tf: marker frame")
    p.add_argument(
        "--joint-states", metavar="TOPIC", help="sensor_msgs/JointState topic (robot pose by kinematics)"
    )
    p.add_argument(
        "--marker-topic", metavar="TOPIC", help="PoseStamped / TransformStamped topic of the marker"
    )
    p.add_argument("--robot-model", help="robot kind whose kinematics turn --joint-states into poses")

    p = command("import-poses", "turn a robot and a tracker TUM trajectory into a raw two-stream recording")
    p.add_argument("--robot", required=True, help="TUM file of base_from_tcp (or flange/gripper) poses")
    p.add_argument(
        "--tracker",
        required=True,
        help="TUM file of tracker_from_marker poses (--eye-in-hand: target_from_camera, camera in target)",
    )
    p.add_argument("--units", choices=["m", "mm"], help="length unit of both files")
    p.add_argument(
        "--eye-in-hand",
        action="store_true",
        help="a camera on the tool looking at a target fixed in the world",
    )
    p.add_argument("-o", "--output", required=True, help="stem of STEM.robot.csv and STEM.tracker.csv")

    p = command(
        "import-easy-handeye", "turn easy_handeye2 saved samples into a recording CSV (spacecal[ros])"
    )
    p.add_argument("samples", help="easy_handeye2 .samples file")
    p.add_argument("-o", "--output", required=True, help="recording CSV to write")

    p = command("check", "confirm before surgery that a calibration still holds")
    p.add_argument("calibration", help="calibration JSON")
    p.add_argument("--recording", help="a recording to check against (instead of moving the robot)")
    add_devices(p)
    p.add_argument("--scenario", help="scenario of the simulated system (default: the calibration's)")
    p.add_argument("--poses", type=integer, choices=[2, 3], help="number of poses")
    p.add_argument("--frames-per-pose", type=integer, help="frames averaged per pose")
    p.add_argument(
        "--threshold-mm",
        type=decimal,
        help="largest TCP error beyond the misfit expected at each pose (default: from the repeatability)",
    )
    p.add_argument(
        "--threshold-deg",
        type=decimal,
        help="largest rotation error, beyond the misfit expected (default: from the repeatability)",
    )
    p.add_argument("--dry-run", action="store_true", help="plan the check poses without moving")

    command("phantom", "the paper's phantom needle biopsy (section 5.3): simulated, or on --robot sim")

    p = command("report", "a self-contained HTML report (works offline) and PNG figures")
    p.add_argument("calibration", help="calibration JSON")
    p.add_argument("--recording", help="recording CSV (default: the calibration's own)")
    p.add_argument("--verification", help="verification JSON (from spacecal verify -o)")
    p.add_argument("--png-dir", help="also write PNG figures here")
    p.add_argument("-o", "--output", required=True, help="HTML file to write")

    p = command("plan", "plan a calibration motion for the smallest predicted error at the site")
    p.add_argument(
        "--budget", type=duration_s, dest="budget_s", metavar="BUDGET", help="motion time budget, e.g. 30s"
    )
    p.add_argument("--scenario", help="the (simulated) set-up to plan for")
    p.add_argument("--frames-per-station", type=integer, help="tracker frames held at each station")
    p.add_argument(
        "--site",
        dest="site_mm",
        metavar="X,Y,Z",
        help="where the needle tip will work, mm in the robot base (default: home)",
    )
    p.add_argument(
        "--needle-path",
        dest="needle_path_mm",
        metavar="EX,EY,EZ,TX,TY,TZ",
        help="a planned needle path (entry, target; mm in the robot base): plan for the needle at its target",
    )
    p.add_argument(
        "--paper-sweeps", action="store_true", help="write the paper's six sweeps from home as the plan"
    )
    p.add_argument("-o", "--output", help="plan JSON to write (run it with acquire/simulate --plan)")

    command("plan-from-slicer", "check a 3D Slicer needle plan in the image, tracker and robot frames")
    add_devices(command("guide", "place the needle on a 3D Slicer plan with the robot (stages, errors)"))
    command("touch", "touch the image fiducials with a tracked pointer: the touched points and registration")
    p = command("doctor", "check a robot and a tracker read-only before a run (nothing moves)")
    add_devices(p, simulated_by_default=False)

    p = command("scenario", "print a scenario preset as JSON, to edit")
    p.add_argument("preset", nargs="?", default=app.DEFAULT_SCENARIO)
    p = command("station", "the calibration station: the whole workflow in a web browser (spacecal[station])")
    p.add_argument("--host", default="127.0.0.1", help="interface (default 127.0.0.1; others need a token)")
    p.add_argument("--port", type=port_number, default=8770, help="TCP port (default 8770; 0: any free one)")
    token = "file of the access token, made when missing (off loopback: it or SPACECAL_STATION_TOKEN)"
    p.add_argument("--token-file", help=token)
    p.add_argument(
        "--data", default="spacecal-station", help="folder for recordings, calibrations and reports"
    )
    p.add_argument("--record", help="the record: SQLite file or database URL (default DATA/record.db)")
    add_thresholds(p)
    p.add_argument("--open", action="store_true", help="open the station in the default web browser")
    p.add_argument(
        "--simulated",
        action="store_true",
        help="offer the simulated robot and tracker (training, demonstrations)",
    )

    return parser


def duration_s(text: str) -> float:
    """``30s``, ``30`` or ``1.5e1 s`` -> seconds; anything else is a usage error."""
    match = re.fullmatch(r"\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*s?\s*", text, re.ASCII)
    if match is None or not math.isfinite(float(match.group(1))):
        raise argparse.ArgumentTypeError(f"takes seconds, e.g. 30s; got {text!r}")
    return float(match.group(1))


def add_thresholds(p: argparse.ArgumentParser) -> None:
    """``--thresholds-mm``: the one grading a calibration's verdict gets (``calibrate``, the station)."""
    limits = "expected-error limits of the verdict's grades, mm (default 0.5,1,2); above POOR: unusable"
    p.add_argument("--thresholds-mm", dest="error_thresholds", metavar="GOOD,ACCEPTABLE,POOR", help=limits)


def add_devices(p: argparse.ArgumentParser, simulated_by_default: bool = True) -> None:
    """The device flags ``acquire``, ``check`` and ``doctor`` share (``app.DeviceSettings``):
    ``--robot``, ``--tracker``, ``--rom``, ``--tracker-rate-hz``, ``--robot-model`` and the tool."""

    def forms(role: str) -> str:
        urls = app.device_url_forms(role)
        return f"sim (default) or {urls}" if simulated_by_default else urls

    # the defaults are the settings' (doctor's: none, it checks only the devices named)
    p.add_argument("--robot", help=forms("robot"))
    p.add_argument("--tracker", help=forms("tracker"))
    p.add_argument("--rom", action="append", help="NDI tool definition of the marker (first) and other tools")
    p.add_argument("--tracker-rate-hz", type=decimal, help="tracker frame rate")
    p.add_argument("--robot-model", help="robot kind (UR10e, FR3, ...; a UR controller takes a UR kind)")
    # --tool-offset-mm is the older, translation-only form of --tool
    p.add_argument(
        "--tool",
        metavar="controller|X,Y,Z,RX,RY,RZ",
        help="the TCP in the flange frame: 'controller' (default) uses the TCP set on the teach pendant; "
        "X,Y,Z,RX,RY,RZ (mm, rotation vector in rad, as the pendant shows it) must match it",
    )
    p.add_argument("--tool-offset-mm", metavar="X,Y,Z", help="same as --tool X,Y,Z,0,0,0")


#: Flags of settings fields that several commands share: a command whose settings have the
#: field gets the flag.
SHARED_FLAGS: dict[str, tuple[str, dict[str, Any]]] = {
    "force": (
        "--force",
        dict(
            action="store_true",
            help="replace an existing output (recording, calibration, result) or an input named as an "
            "output (written atomically)",
        ),
    ),
    "accept_edited": (
        "--accept-edited",
        dict(
            action="store_true",
            help="use a calibration edited since it was written, or a recording changed since calibrating",
        ),
    ),
    "record": (
        "--record",
        dict(
            metavar="PATH_OR_URL",
            help="also write the result to this record (SQLite file or database URL; spacecal[station])",
        ),
    ),
    "accept_other_devices": (
        "--accept-other-devices",
        dict(action="store_true", help="use other real devices than the calibration records (URLs, model)"),
    ),
    "confirm_robot_motion": (
        "--confirm-robot-motion",
        dict(action="store_true", help="needed to move a robot"),
    ),
    "workspace_box": (
        "--workspace-box",
        dict(metavar="XMIN,XMAX,YMIN,YMAX,ZMIN,ZMAX", help="base-frame box (mm) to stay in"),
    ),
}


def join_negative_coordinates(argv: list[str]) -> list[str]:
    """``--target -573,-168,327`` -> ``--target=-573,-168,327``: base-frame coordinates are often
    negative, and argparse would take such a value for an option."""
    joined, rest = [], list(argv)
    while rest:
        item = rest.pop(0)
        if item in COORDINATE_OPTIONS and rest and rest[0][:1] == "-" and rest[0][1:2].isdigit():
            item = f"{item}={rest.pop(0)}"
        joined.append(item)
    return joined
