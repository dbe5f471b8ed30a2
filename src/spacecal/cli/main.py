"""The ``spacecal`` command line: a thin shell over one library function per command.

Exit codes: 0 success; 1 a known error, printed as one line (``--debug`` shows the
traceback); 2 a usage error.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from spacecal import __version__
from spacecal.core.errors import InvalidInputError, SpacecalError


class CheckFailed(SpacecalError):
    """A calibration check did not pass (exit code 1, like any known failure)."""


def _cmd_simulate(args) -> None:
    import dataclasses

    from spacecal.io.recording_csv import metadata_path, write_recording
    from spacecal.experiments.simulation import simulate
    from spacecal.sim.scenario import load_scenario

    scenario = load_scenario(args.scenario)
    if args.seed is not None:
        scenario = dataclasses.replace(scenario, seed=args.seed)
    if args.raw:
        from spacecal.io.raw_streams import write_raw_recording
        from spacecal.experiments.simulation import simulate_raw

        raw, _ = simulate_raw(scenario, args.clock_offset_ms / 1000.0)
        stem = str(args.output)[:-4] if str(args.output).endswith(".csv") else str(args.output)
        robot_path, tracker_path = write_raw_recording(raw, stem)
        print(
            f"wrote {robot_path} ({len(raw.robot_time_s)} robot states) and {tracker_path} "
            f"({len(raw.tracker_time_s)} tracker frames); robot clock {args.clock_offset_ms} ms ahead"
        )
        return
    simulation = simulate(scenario)
    path = write_recording(simulation.recording, args.output)
    rec = simulation.recording
    print(
        f"wrote {path} ({len(rec)} samples, {int(rec.visible.sum())} with the marker visible) "
        f"and {metadata_path(path)}"
    )
    print(
        f"scenario {scenario.name}, seed {scenario.seed}; planned motion time "
        f"{simulation.plan.motion_time_s:.1f} s"
    )
    for message in simulation.plan.messages:
        print(f"note: {message}")


def _parse_points(texts, option: str):
    """``["x,y,z", ...]`` -> (M, 3) array, or None."""
    if not texts:
        return None
    points = []
    for text in texts:
        try:
            values = [float(v) for v in text.split(",")]
        except ValueError:
            values = []
        if len(values) != 3:
            raise InvalidInputError(f"{option} takes x,y,z in mm, got {text!r}")
        points.append(values)
    return points


def _cmd_calibrate(args) -> None:
    from spacecal.estimators import calibrate
    from spacecal.io.recording_csv import read_recording
    from spacecal.io.results_json import write_calibration

    offset_note = None
    if args.tracker_stream:
        from spacecal.estimators.time_offset import estimate_time_offset, pair_streams
        from spacecal.io.raw_streams import read_raw_recording

        raw = read_raw_recording(args.recording, args.tracker_stream)
        if args.time_offset_ms == "estimate":
            offset = estimate_time_offset(raw).offset_s
            offset_note = f"clock offset estimated: robot clock {offset * 1000:.2f} ms ahead of the tracker's"
        else:
            try:
                offset = float(args.time_offset_ms) / 1000.0
            except ValueError:
                raise InvalidInputError("--time-offset-ms takes a number or 'estimate'") from None
            offset_note = f"clock offset given: {offset * 1000:.2f} ms"
        recording = pair_streams(raw, offset)
    else:
        recording = read_recording(args.recording)
    options = {}
    if args.target:
        options["targets_in_base"] = _parse_points(args.target, "--target")
    if args.sigma_mm is not None:
        if not args.sigma_mm > 0:
            raise InvalidInputError("--sigma-mm must be a positive number of millimetres")
        options["sigma_mm"] = args.sigma_mm
    result = calibrate(recording, args.method, **options)
    result.source = {"recording": str(Path(args.recording).resolve())}
    if offset_note:
        result.diagnostics["time_offset_s"] = recording.metadata["paired_with_offset_s"]
        print(offset_note)
    path = write_calibration(result, args.output)
    counts = result.sample_counts
    print(f"wrote {path} (method {result.method}; {counts['used']} of {counts['total']} samples used)")
    diagnostics = result.diagnostics
    sphere = diagnostics.get("sphere")
    if sphere:
        print(
            f"sphere: radius {sphere['radius_mm']:.2f} mm, fit RMS {sphere['rms_mm']:.3f} mm; "
            "line straightness RMS: "
            + ", ".join(f"{k} {v['straightness_rms_mm']:.3f} mm" for k, v in diagnostics["lines"].items())
        )
    if "residual_position_rms_mm" in diagnostics:
        print(
            f"residuals: marker position RMS {diagnostics['residual_position_rms_mm']:.3f} mm, "
            f"rotation RMS {diagnostics['residual_rotation_rms_deg']:.3f} deg"
        )
    if result.predicted_tre_mm:
        tre = result.predicted_tre_mm
        print(
            f"predicted TRE: {tre['site']:.3f} mm at the site, {tre['cube_rms']:.3f} mm RMS over a "
            f"{tre['cube_side_mm']:.0f} mm cube around it"
        )
        for target in tre.get("targets", []):
            print(f"  at {target['target_in_base_mm']}: {target['tre_mm']:.3f} mm")
    if "outliers" in diagnostics:
        print(f"outliers: {len(diagnostics['outliers'])} frames flagged (listed in the result file)")
    if "verdict" in diagnostics:
        print(f"verdict: {diagnostics['verdict']}")


def _scenario_for_verification(args, calibration):
    from spacecal.io.recording_csv import metadata_path
    from spacecal.io.results_json import read_json_object
    from spacecal.sim.scenario import load_scenario, scenario_from_dict

    if args.scenario is not None:
        return load_scenario(args.scenario)
    recording = calibration.source.get("recording")
    meta = metadata_path(recording) if recording else None
    if meta is None or not meta.is_file():
        raise InvalidInputError(
            "no scenario given and the calibration's recording metadata was not found; pass --scenario"
        )
    data = read_json_object(meta, "recording metadata")
    if "scenario" not in data:
        raise InvalidInputError(f"{meta} holds no simulation scenario (real data?); pass --scenario")
    return scenario_from_dict(data["scenario"])


def _cmd_verify(args) -> None:
    from spacecal.io.results_json import read_calibration, write_json
    from spacecal.report.figures import plot_verification_errors
    from spacecal.experiments.verification import verify_in_simulation

    calibration = read_calibration(args.calibration)
    scenario = _scenario_for_verification(args, calibration)
    if args.points < 1:
        raise InvalidInputError("--points must be at least 1")
    result = verify_in_simulation(calibration, scenario, args.points)
    stats = result.statistics()
    if args.output:
        print(f"wrote {write_json(result.to_dict(), args.output)}")
    if args.figure:
        print(
            f"wrote {plot_verification_errors(result.position_error_mm, result.posture_error_deg, args.figure)}"
        )
    pos, ang = stats["position_mm"], stats["posture_deg"]
    print(f"verification on {len(result.position_error_mm)} needle poses (scenario {scenario.name}):")
    print(
        f"  position error min / mean / max / RMS: {pos['min']:.3f} / {pos['mean']:.3f} / "
        f"{pos['max']:.3f} / {pos['rms']:.3f} mm   (paper: min 0.87, mean < 1.05 mm)"
    )
    print(
        f"  posture error  min / mean / max / RMS: {ang['min']:.3f} / {ang['mean']:.3f} / "
        f"{ang['max']:.3f} / {ang['rms']:.3f} deg  (paper: min 0.83, mean about 1.1 deg)"
    )


def _cmd_demo(args) -> None:
    from spacecal.experiments.demo import run_demo
    from spacecal.sim.scenario import load_scenario

    result = run_demo(load_scenario(args.scenario))
    print(result.table())
    if args.out:
        _write_demo_outputs(result, Path(args.out))


def _write_demo_outputs(result, output_dir: Path) -> None:
    from spacecal.io.recording_csv import write_recording
    from spacecal.io.results_json import write_calibration, write_json
    from spacecal.report.figures import plot_verification_errors

    recording_path = write_recording(result.simulation.recording, output_dir / "recording.csv")
    result.calibration.source = {"recording": str(recording_path.resolve())}
    write_calibration(result.calibration, output_dir / "calibration.json")
    write_json(result.verification.to_dict(), output_dir / "verification.json")
    plot_verification_errors(
        result.verification.position_error_mm,
        result.verification.posture_error_deg,
        output_dir / "verification_errors.png",
    )
    print(
        f"\nwrote recording.csv, calibration.json, verification.json, verification_errors.png to {output_dir}"
    )


def _cmd_pivot(args) -> None:
    from spacecal.estimators.pivot import pivot_calibration
    from spacecal.io.pose_files import read_matrix_folder
    from spacecal.io.recording_csv import read_recording
    from spacecal.io.results_json import write_json

    source = Path(args.poses)
    if source.is_dir():
        names = Path(args.subset).read_text().split() if args.subset else None
        poses = read_matrix_folder(source, names)
    else:
        poses = read_recording(source).tracker_from_marker_stack
    result = pivot_calibration(poses, args.method)
    summary = result.to_dict()
    if args.output:
        print(f"wrote {write_json(summary, args.output)}")
    print(f"pivot calibration ({result.method}, {summary['frames']} frames)")
    print("  tip in marker   (mm): " + ", ".join(f"{v:.3f}" for v in result.tip_in_marker))
    print("  pivot in tracker (mm): " + ", ".join(f"{v:.3f}" for v in result.pivot_in_tracker))
    print(
        f"  residual: RMS {result.rms_mm:.3f} mm (3-D), {result.rms_per_axis_mm:.3f} mm per axis "
        f"(scikit-surgerycalibration's figure), mean {summary['residual_mean_mm']:.3f}, "
        f"max {summary['residual_max_mm']:.3f} mm"
    )


def _cmd_bound(args) -> None:
    from spacecal.estimators.likelihood import tre_lower_bound
    from spacecal.io.recording_csv import read_recording
    from spacecal.io.results_json import read_calibration

    if not args.sigma_mm > 0:
        raise InvalidInputError("--sigma-mm must be a positive number of millimetres")
    recording = read_recording(args.recording)
    calibration = read_calibration(args.calibration)
    bound = tre_lower_bound(
        recording,
        calibration.tracker_from_base,
        calibration.tcp_from_marker,
        args.sigma_mm,
        _parse_points(args.target, "--target"),
    )
    print(
        f"Cramer-Rao lower bound on TRE for {args.recording} with {args.sigma_mm} mm per-axis sphere noise:"
    )
    print(
        f"  {bound['site']:.4f} mm at the site, {bound['cube_rms']:.4f} mm RMS over a "
        f"{bound['cube_side_mm']:.0f} mm cube around it"
    )
    for target in bound.get("targets", []):
        print(f"  at {target['target_in_base_mm']}: {target['tre_mm']:.4f} mm")


def _sim_devices(args):
    """The simulated robot and tracker of a scenario, and its world."""
    from spacecal.sim.devices import SimClock, SimulatedRobot, SimulatedTracker
    from spacecal.sim.scenario import load_scenario
    from spacecal.sim.world import build_world

    world = build_world(load_scenario(args.scenario))
    robot = SimulatedRobot(world, SimClock())
    return world, robot, SimulatedTracker(world, robot)


def _progress_printer(total_moves: int):
    """A one-line progress display on stderr: bar, move, samples, markers seen."""

    def show(samples: int, visible: int, move_index: int, label: str) -> None:
        if samples % 10 and sys.stderr.isatty():
            return
        if not sys.stderr.isatty() and samples % 100:
            return
        done = (move_index + 1) / total_moves
        bar = "#" * int(30 * done) + "." * (30 - int(30 * done))
        end = "\r" if sys.stderr.isatty() else "\n"
        print(
            f"[{bar}] move {move_index + 1}/{total_moves} {label:8s} samples {samples} "
            f"(marker seen {visible})",
            end=end,
            file=sys.stderr,
            flush=True,
        )

    return show


def _check_workspace(plan, box_text: str | None) -> list[str]:
    """Sampled plan poses outside a base-frame box ``xmin,xmax,ymin,ymax,zmin,zmax`` (mm)."""
    import numpy as np

    if not box_text:
        return []
    try:
        box = np.array([float(v) for v in box_text.split(",")]).reshape(3, 2)
    except ValueError:
        raise InvalidInputError("--workspace-box takes xmin,xmax,ymin,ymax,zmin,zmax in mm") from None
    problems = []
    for move in plan.moves:
        positions = move.poses_at(np.linspace(0.0, move.duration_s, 21))[:, :3, 3]
        outside = (positions < box[:, 0]) | (positions > box[:, 1])
        if outside.any():
            problems.append(
                f"{move.label} move leaves the workspace box (up to "
                f"{np.max(np.maximum(box[:, 0] - positions, positions - box[:, 1])):.0f} mm)"
            )
    return problems


def _cmd_acquire(args) -> None:
    if args.robot != "sim" or args.tracker != "sim":
        robot, tracker, world = _hardware_devices(args)
    else:
        world, robot, tracker = _sim_devices(args)
    try:
        _run_acquisition(args, robot, tracker, world)
    finally:
        for device in (robot, tracker):
            close = getattr(device, "close", None)
            if close:
                try:
                    close()
                except OSError:
                    pass  # closing must not mask the error that stopped the run


def _run_acquisition(args, robot, tracker, world) -> None:
    from spacecal.experiments.simulation import plan_for_world, recording_metadata
    from spacecal.workflows.acquisition import AcquisitionSettings, acquire

    plan = plan_for_world(world) if world is not None else _hardware_plan(args, robot)
    problems = _check_workspace(plan, args.workspace_box)
    print(f"plan: {len(plan.moves)} moves, {plan.motion_time_s:.1f} s of motion")
    for message in plan.messages + problems:
        print(f"note: {message}")
    if problems:
        raise InvalidInputError("the plan leaves the workspace box; nothing was moved")
    if args.dry_run:
        print(
            "dry run: plan checked (reach, joint limits, visibility in the model, workspace box); nothing moved"
        )
        return
    if args.robot != "sim" and not args.confirm_robot_motion:
        raise InvalidInputError(
            "moving a real robot needs --confirm-robot-motion (check the workspace is clear)"
        )
    metadata = recording_metadata(world) if world is not None else _hardware_metadata(args)
    settings = AcquisitionSettings(linear_speed_mm_s=args.speed_mm_s, linear_accel_mm_s2=args.accel_mm_s2)
    result = acquire(
        plan,
        robot,
        tracker,
        args.output,
        metadata,
        settings,
        resume=args.resume,
        on_sample=_progress_printer(len(plan.moves)),
    )
    print(
        f"\nwrote {result.recording_path}: {result.samples_written} samples, "
        f"{result.visible_written} with the marker seen; {result.moves_completed}/{result.moves_total} moves"
    )


def _hardware_devices(args):
    """Open the robot and tracker named by --robot / --tracker (this is where hardware is chosen)."""
    from spacecal.adapters import parse_device_url

    if args.robot == "sim" or args.tracker == "sim":
        raise InvalidInputError("use --robot sim with --tracker sim, or real devices for both")
    _, host, _ = parse_device_url(args.robot, ("ur",))
    scheme, address, port = parse_device_url(args.tracker, ("ndi", "igtl"))
    if scheme == "ndi":
        from spacecal.adapters.ndi import VEGA_DEFAULT_PORT, NDITracker

        if not args.rom:
            raise InvalidInputError("an NDI tracker needs the marker's tool definition: --rom FILE")
        serial = address.startswith("/")
        tracker = NDITracker(
            address, None if serial else (port or VEGA_DEFAULT_PORT), args.rom, rate_hz=args.tracker_rate_hz
        )
    else:
        from spacecal.adapters.igtl import IGTLTracker

        tracker = IGTLTracker(address, port or 18944)
    from spacecal.adapters.ur import URRobot

    robot = URRobot(host, control=not args.dry_run)
    return robot, tracker, None


def _hardware_model(args):
    from spacecal.geometry.transforms import make_transform
    from spacecal.models.kinematics import ur_model

    offset = _parse_points([args.tool_offset_mm], "--tool-offset-mm")[0]
    return ur_model(args.robot_model, make_transform(np.eye(3), offset))


def _hardware_plan(args, robot):
    """The paper's sweeps from the robot's current configuration (its home)."""
    from spacecal.io.results_json import read_calibration
    from spacecal.models.kinematics import forward_kinematics
    from spacecal.models.marker import ndi_8700339_like
    from spacecal.models.tracker import TrackerModel
    from spacecal.planning.motion import MotionLimits
    from spacecal.planning.paper_sweeps import PaperSweepSettings, plan_paper_sweeps
    from spacecal.planning.visibility import VisibilityModel
    from spacecal.workflows.acquisition import resume_home_joints

    model = _hardware_model(args)
    state = robot.state()
    home_joints = resume_home_joints(args.output) if args.resume else None
    predicted = forward_kinematics(model, state.joints_rad)
    mismatch = float(np.linalg.norm(predicted[:3, 3] - state.base_from_tcp[:3, 3]))
    if mismatch > 1.0:
        raise InvalidInputError(
            f"--robot-model/--tool-offset-mm put the TCP {mismatch:.1f} mm from where the controller reports it; "
            "they must match the TCP configured on the robot"
        )
    visibility = None
    if args.prior:
        prior = read_calibration(args.prior)
        visibility = VisibilityModel(
            TrackerModel(), ndi_8700339_like(), prior.tracker_from_base, prior.tcp_from_marker
        )
    settings = PaperSweepSettings(
        rotation_each_way_deg=args.rotation_deg,
        translation_stroke_mm=args.translation_mm,
        limits=MotionLimits(
            linear_speed_mm_s=args.speed_mm_s,
            linear_accel_mm_s2=args.accel_mm_s2,
            angular_speed_rad_s=np.radians(args.angular_speed_deg_s),
        ),
    )
    # On resume the plan is rebuilt from the home it was made from, not from where the robot stopped.
    plan = plan_paper_sweeps(
        model, state.joints_rad if home_joints is None else home_joints, settings, visibility
    )
    if visibility is None:
        plan.messages.append("no --prior calibration: marker visibility was not checked")
    return plan


def _hardware_metadata(args):
    from spacecal.models.marker import ndi_8700339_like

    model = _hardware_model(args)
    return {
        "robot": {"model": model.name, "url": args.robot, "flange_from_tcp": model.flange_from_tcp.tolist()},
        "tracker": {"url": args.tracker, "rate_hz": args.tracker_rate_hz},
        "marker": ndi_8700339_like().to_dict(),
        "units": {"length": "mm", "angle": "rad", "time": "s"},
        "source": "spacecal acquire",
    }


def _cmd_register_landmarks(args) -> None:
    from spacecal.estimators.landmarks import LandmarkDetectionSettings
    from spacecal.io.plus_config import read_plus_landmarks, read_plus_transform
    from spacecal.io.plus_sequence import read_plus_sequence
    from spacecal.io.results_json import write_json
    from spacecal.workflows.landmark_registration import register_landmarks_from_stylus

    sequence = read_plus_sequence(args.sequence)
    _, landmarks = read_plus_landmarks(args.config)
    stylus_from_tip = read_plus_transform(args.config, "StylusTip", "Stylus")
    settings = None
    if args.plus_compatible:
        times = sequence.timestamps_s
        spacing = min(np.linalg.norm(a - b) for i, a in enumerate(landmarks) for b in landmarks[i + 1 :])
        settings = LandmarkDetectionSettings(
            acquisition_rate_hz=1.0 / (times[1] - times[0]),
            min_landmark_spacing_mm=spacing,
            plus_compatible=True,
        )
    result = register_landmarks_from_stylus(
        sequence.timestamps_s,
        sequence.transform(f"{args.reference}ToTracker"),
        sequence.transform(f"{args.stylus}ToTracker"),
        stylus_from_tip,
        landmarks,
        settings,
    )
    reg = result.registration
    if args.output:
        print(f"wrote {write_json(result.to_dict(), args.output)}")
    print(
        f"registered {len(landmarks)} landmarks (detected at "
        + ", ".join(f"{t - sequence.timestamps_s[0]:.1f}" for t in result.detected_at_s)
        + " s)"
    )
    print("reference_from_phantom:")
    for row in reg.target_from_source:
        print("  " + "  ".join(f"{v:11.6f}" for v in row))
    print(
        f"landmark error: mean {reg.fre_mean_mm:.3f} mm (PLUS's 'Error'), RMS {reg.fre_rms_mm:.3f} mm; "
        f"per landmark " + ", ".join(f"{v:.2f}" for v in reg.residuals_mm)
    )


def _cmd_export(args) -> None:
    from spacecal.io.plus_config import write_plus_coordinate_definitions
    from spacecal.io.results_json import read_calibration
    from spacecal.io.slicer import write_slicer_transform

    calibration = read_calibration(args.calibration)
    if not (args.slicer or args.plus or args.igtl):
        raise InvalidInputError(
            "say where to export: --slicer FILE.tfm, --plus FILE.xml and/or --igtl HOST:PORT"
        )
    error = (calibration.predicted_tre_mm or {}).get("site")
    if args.slicer:
        print(
            f"wrote {write_slicer_transform(calibration.tracker_from_base, args.slicer)} "
            "(loads in 3D Slicer as BaseToTracker; its matrix is tracker_from_base)"
        )
    if args.plus:
        path = write_plus_coordinate_definitions(
            args.plus,
            [
                (calibration.tracker_from_base, "Base", "Tracker", error),
                (calibration.tcp_from_marker, "Marker", "TCP", None),
            ],
        )
        print(f"wrote {path} (PLUS CoordinateDefinitions: BaseToTracker, MarkerToTCP)")
    if args.igtl:
        from spacecal.adapters import parse_device_url
        from spacecal.adapters.igtl import publish_transform

        _, host, port = parse_device_url("igtl://" + args.igtl, ("igtl",))
        publish_transform(host, port or 18944, "BaseToTracker", calibration.tracker_from_base)
        print(f"sent BaseToTracker to igtl://{host}:{port or 18944}")


def _cmd_import_plus(args) -> None:
    from spacecal.io.plus_import import recording_from_plus_sequence
    from spacecal.io.recording_csv import write_recording

    recording = recording_from_plus_sequence(args.sequence, args.marker, args.tcp, args.segment)
    path = write_recording(recording, args.output)
    print(f"wrote {path}: {len(recording)} frames, {int(recording.visible.sum())} with the marker seen")


def _cmd_check(args) -> None:
    from spacecal.io.recording_csv import read_recording
    from spacecal.io.results_json import read_calibration
    from spacecal.workflows.check import append_history, check_with_recording, check_with_robot

    calibration = read_calibration(args.calibration)
    if args.recording:
        result = check_with_recording(
            calibration, read_recording(args.recording), args.threshold_mm, args.threshold_deg
        )
    elif args.robot == "sim":
        from spacecal.planning.check_poses import check_joints
        from spacecal.sim.devices import SimClock, SimulatedRobot, SimulatedTracker
        from spacecal.sim.world import build_world

        world = build_world(_scenario_for_verification(args, calibration))
        robot = SimulatedRobot(world, SimClock())
        result = check_with_robot(
            calibration,
            robot,
            SimulatedTracker(world, robot),
            check_joints(world.nominal_model, world.home_joints_rad, args.poses),
            args.threshold_mm,
            args.threshold_deg,
        )
    else:
        raise InvalidInputError(
            "check on real hardware: record two or three static poses with "
            "'spacecal acquire' and pass them with --recording"
        )
    history = append_history(args.calibration, result)
    for pose in result.to_dict()["poses"]:
        print(
            f"  {pose['label']:>10}: TCP {pose['tcp_error_mm']:.3f} mm, rotation {pose['rotation_error_deg']:.3f} deg"
        )
    verdict = "PASS" if result.passed else "FAIL"
    print(
        f"{verdict}: thresholds {result.threshold_mm} mm and {result.threshold_deg} deg (history: {history})"
    )
    if not result.passed:
        raise CheckFailed("the calibration no longer holds: recalibrate (marker bumped, tracker moved?)")


def _cmd_phantom(args) -> None:
    from spacecal.io.results_json import write_json
    from spacecal.report.figures import plot_phantom_errors
    from spacecal.experiments.phantom import PhantomSettings, run_phantom_experiment
    from spacecal.sim.scenario import load_scenario

    if args.cases < 1:
        raise InvalidInputError("--cases must be at least 1")
    result = run_phantom_experiment(
        load_scenario(args.scenario), args.method, PhantomSettings(cases=args.cases)
    )
    print(result.table())
    print("(measured errors include the second CT's localisation error, as in the paper's experiment)")
    if args.output:
        print(f"wrote {write_json(result.to_dict(), args.output)}")
    if args.figure:
        print(
            f"wrote {plot_phantom_errors(result.entry_error_mm, result.target_error_mm, result.direction_error_deg, args.figure)}"
        )


def _cmd_report(args) -> None:
    from spacecal.io.recording_csv import read_recording
    from spacecal.io.results_json import read_calibration, read_json_object
    from spacecal.report.html import Report, write_report
    from spacecal.workflows.check import read_history

    calibration = read_calibration(args.calibration)
    recording_path = args.recording or calibration.source.get("recording")
    recording = read_recording(recording_path) if recording_path and Path(recording_path).is_file() else None
    verification = read_json_object(args.verification, "verification") if args.verification else None
    report = Report(calibration, recording, verification, read_history(args.calibration))
    path, titles = write_report(report, args.output, args.png_dir)
    print(f"wrote {path} ({len(titles)} plots: {', '.join(titles)})")
    if recording is None:
        print("note: no recording found (pass --recording) - sweeps and residuals are not shown")


def _parse_seconds(text: str) -> float:
    value = text[:-1] if text.endswith("s") else text
    try:
        seconds = float(value)
    except ValueError:
        raise InvalidInputError(f"--budget takes seconds, e.g. 30s; got {text!r}") from None
    if seconds <= 0:
        raise InvalidInputError("--budget must be positive")
    return seconds


def _cmd_plan(args) -> None:
    from spacecal.io.results_json import write_json
    from spacecal.planning.optimal import PlannerSettings, paper_sweep_site_error, plan_for_site
    from spacecal.planning.visibility import VisibilityModel
    from spacecal.experiments.simulation import plan_for_world
    from spacecal.sim.scenario import load_scenario
    from spacecal.sim.world import build_world

    world = build_world(load_scenario(args.scenario))
    visibility = VisibilityModel(world.tracker, world.marker, world.tracker_from_base, world.tcp_from_marker)
    settings = PlannerSettings(
        budget_s=_parse_seconds(args.budget),
        frames_per_station=args.frames_per_station,
        sphere_sigma_mm=world.scenario.white_noise_rms_mm / np.sqrt(3) or 0.1,
    )
    planned = plan_for_site(
        world.nominal_model,
        world.home_joints_rad,
        visibility,
        np.random.default_rng([world.scenario.seed, 7]),
        settings,
    )
    paper = plan_for_world(world)
    paper_error = paper_sweep_site_error(world.nominal_model, paper, visibility, settings)
    print(
        f"planned: {len(planned.station_joints_rad)} stations, {planned.motion_time_s:.1f} s of motion, "
        f"predicted tip error at the site {planned.predicted_error_mm:.3f} mm"
    )
    print(
        f"paper's sweeps: {paper.motion_time_s:.1f} s of motion, predicted tip error at the site {paper_error:.3f} mm"
    )
    print(
        "(predicted for a joint fit of the calibration and the robot's DH corrections: spacecal calibrate --method kinematic)"
    )
    if args.output:
        data = {
            "schema": "spacecal.plan",
            "schema_version": 1,
            "budget_s": settings.budget_s,
            "motion_time_s": planned.motion_time_s,
            "predicted_error_mm": planned.predicted_error_mm,
            "paper_sweep": {"motion_time_s": paper.motion_time_s, "predicted_error_mm": paper_error},
            "home_joints_rad": world.home_joints_rad.tolist(),
            "station_joints_rad": planned.station_joints_rad.tolist(),
            "moves": planned.plan.summary()["moves"],
        }
        print(f"wrote {write_json(data, args.output)}")


def _cmd_scenario(args) -> None:
    from spacecal.sim.scenario import load_scenario

    print(json.dumps(load_scenario(args.preset).to_dict(), indent=2))


def build_parser() -> argparse.ArgumentParser:
    from spacecal.estimators import METHODS

    parser = argparse.ArgumentParser(
        prog="spacecal", description="Calibrate a surgical robot's base frame to an optical tracker."
    )
    parser.add_argument("--version", action="version", version=f"spacecal {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = commands.add_parser("simulate", help="simulate the paper's calibration run -> recording CSV")
    p.add_argument("--scenario", help="scenario JSON file or preset (paper-realistic, paper-white)")
    p.add_argument("--seed", type=int, help="override the scenario's seed")
    p.add_argument(
        "--raw", action="store_true", help="write the two raw streams (STEM.robot.csv, STEM.tracker.csv)"
    )
    p.add_argument(
        "--clock-offset-ms", type=float, default=0.0, help="with --raw: robot clock ahead of the tracker's"
    )
    p.add_argument("-o", "--output", required=True, help="recording CSV to write (with --raw: the stem)")
    p.set_defaults(run=_cmd_simulate)

    p = commands.add_parser("calibrate", help="estimate tracker_from_base from a recording")
    p.add_argument("recording", help="recording CSV (or, with --tracker-stream, the robot stream)")
    p.add_argument(
        "--method", default="paper", help=f"estimator: {', '.join(sorted(METHODS))} (default paper)"
    )
    p.add_argument("--tracker-stream", help="the raw tracker stream: pair it with the robot stream first")
    p.add_argument(
        "--time-offset-ms",
        default="estimate",
        help="with --tracker-stream: robot clock minus tracker clock, or 'estimate' (default)",
    )
    p.add_argument("-o", "--output", required=True, help="calibration JSON to write")
    p.add_argument(
        "--target",
        action="append",
        metavar="X,Y,Z",
        help="point in the base frame (mm) to predict the TRE at (ml, robust); repeatable",
    )
    p.add_argument(
        "--sigma-mm",
        type=float,
        help="per-axis sphere noise (ml, robust); default: estimated from marker_rms_mm",
    )
    p.set_defaults(run=_cmd_calibrate)

    p = commands.add_parser("pivot", help="pivot calibration of a pointer or needle tip")
    p.add_argument("poses", help="folder of 4x4 .txt pose files, or a recording CSV")
    p.add_argument("--method", default="aos", help="aos (algebraic one-step, default) or sphere")
    p.add_argument("--subset", help="file listing the pose file names to use")
    p.add_argument("-o", "--output", help="pivot result JSON to write")
    p.set_defaults(run=_cmd_pivot)

    p = commands.add_parser("bound", help="Cramer-Rao lower bound on TRE for a recording")
    p.add_argument("recording", help="recording CSV")
    p.add_argument("--calibration", required=True, help="calibration JSON (where to evaluate the bound)")
    p.add_argument("--sigma-mm", type=float, required=True, help="per-axis sphere noise, mm")
    p.add_argument(
        "--target", action="append", metavar="X,Y,Z", help="point in the base frame (mm); repeatable"
    )
    p.set_defaults(run=_cmd_bound)

    p = commands.add_parser("verify", help="the paper's verification experiment on the simulated system")
    p.add_argument("calibration", help="calibration JSON")
    p.add_argument("--scenario", help="scenario (default: the one stored with the calibration's recording)")
    p.add_argument("--points", type=int, default=15, help="number of needle poses (default 15)")
    p.add_argument("-o", "--output", help="verification JSON to write")
    p.add_argument("--figure", help="PNG of the error curves (paper Fig. 7)")
    p.set_defaults(run=_cmd_verify)

    p = commands.add_parser("demo", help="simulate, calibrate and verify; print a summary table")
    p.add_argument("--scenario", help="scenario JSON file or preset (default paper-realistic)")
    p.add_argument("--out", help="directory to write the recording, calibration, verification and figure to")
    p.set_defaults(run=_cmd_demo)

    p = commands.add_parser(
        "acquire", help="run the calibration motion on a robot while sampling the tracker"
    )
    p.add_argument("--robot", default="sim", help="sim (default) or ur://HOST")
    p.add_argument("--tracker", default="sim", help="sim (default), ndi://PORT_OR_HOST or igtl://HOST:PORT")
    p.add_argument("--scenario", help="scenario for the simulated devices (default paper-realistic)")
    p.add_argument("-o", "--output", required=True, help="recording CSV to write (each sample flushed)")
    p.add_argument("--dry-run", action="store_true", help="check the plan without moving")
    p.add_argument("--resume", action="store_true", help="continue a stopped acquisition of the same plan")
    p.add_argument("--confirm-robot-motion", action="store_true", help="required to move a real robot")
    p.add_argument("--speed-mm-s", type=float, default=100.0, help="TCP speed (default 100 mm/s)")
    p.add_argument("--accel-mm-s2", type=float, default=400.0, help="TCP acceleration (default 400 mm/s^2)")
    p.add_argument(
        "--workspace-box",
        metavar="XMIN,XMAX,YMIN,YMAX,ZMIN,ZMAX",
        help="base-frame box (mm) the TCP must stay in",
    )
    p.add_argument("--rom", action="append", help="NDI tool definition of the marker (first) and other tools")
    p.add_argument("--tracker-rate-hz", type=float, default=20.0, help="NDI frame rate (Vicra 20, Vega 60)")
    p.add_argument("--robot-model", default="UR10", help="UR model for planning checks (default UR10)")
    p.add_argument("--tool-offset-mm", default="0,0,0", help="TCP in the flange frame, as set on the robot")
    p.add_argument("--prior", help="an earlier calibration, to check marker visibility along the plan")
    p.add_argument("--rotation-deg", type=float, default=90.0, help="rotation sweep each way (default 90)")
    p.add_argument(
        "--translation-mm", type=float, default=500.0, help="translation sweep length (default 500)"
    )
    p.add_argument("--angular-speed-deg-s", type=float, default=45.0, help="TCP rotation speed (default 45)")
    p.set_defaults(run=_cmd_acquire)

    p = commands.add_parser(
        "register-landmarks",
        help="register a phantom to its reference marker from a tracked-stylus PLUS recording",
    )
    p.add_argument(
        "sequence", help="PLUS sequence file (.igs.mha) with <Reference>ToTracker and <Stylus>ToTracker"
    )
    p.add_argument(
        "--config", required=True, help="PLUS device set: StylusTip->Stylus transform and <Landmarks>"
    )
    p.add_argument("--reference", default="Reference", help="reference tool name (default Reference)")
    p.add_argument("--stylus", default="Stylus", help="stylus tool name (default Stylus)")
    p.add_argument(
        "--plus-compatible", action="store_true", help="average landmark frames exactly as PLUS does"
    )
    p.add_argument("-o", "--output", help="registration JSON to write")
    p.set_defaults(run=_cmd_register_landmarks)

    p = commands.add_parser("export", help="export a calibration to 3D Slicer, PLUS, or over OpenIGTLink")
    p.add_argument("calibration", help="calibration JSON")
    p.add_argument("--slicer", help="ITK transform file (.tfm) for 3D Slicer")
    p.add_argument("--plus", help="PLUS CoordinateDefinitions XML")
    p.add_argument(
        "--igtl", metavar="HOST:PORT", help="send BaseToTracker to an OpenIGTLink server (e.g. Slicer)"
    )
    p.set_defaults(run=_cmd_export)

    p = commands.add_parser("import-plus", help="turn a PLUS sequence file (.igs.mha) into a recording CSV")
    p.add_argument("sequence", help="PLUS sequence file")
    p.add_argument(
        "--marker", default="MarkerToTracker", help="marker transform name (default MarkerToTracker)"
    )
    p.add_argument("--tcp", default="TCPToBase", help="robot TCP transform name (default TCPToBase)")
    p.add_argument("--segment", default="static", help="segment label for every frame")
    p.add_argument("-o", "--output", required=True, help="recording CSV to write")
    p.set_defaults(run=_cmd_import_plus)

    p = commands.add_parser("check", help="confirm before surgery that a calibration still holds")
    p.add_argument("calibration", help="calibration JSON")
    p.add_argument("--recording", help="static poses to check against (instead of moving the robot)")
    p.add_argument("--robot", default="sim", help="sim (default): move the simulated robot")
    p.add_argument("--scenario", help="scenario of the simulated system (default: the calibration's)")
    p.add_argument("--poses", type=int, default=3, choices=[2, 3], help="number of poses (2 or 3)")
    p.add_argument(
        "--threshold-mm", type=float, default=1.0, help="largest TCP error that passes (default 1 mm)"
    )
    p.add_argument("--threshold-deg", type=float, default=1.0, help="largest rotation error that passes")
    p.set_defaults(run=_cmd_check)

    p = commands.add_parser("phantom", help="the paper's phantom needle biopsy (§5.3) in simulation")
    p.add_argument("--scenario", help="scenario JSON file or preset (default paper-realistic)")
    p.add_argument("--method", default="paper", help="calibration method (default paper)")
    p.add_argument("--cases", type=int, default=5, help="needle paths (default 5, as in the paper)")
    p.add_argument("-o", "--output", help="results JSON to write")
    p.add_argument("--figure", help="PNG of the error curves (paper Fig. 9)")
    p.set_defaults(run=_cmd_phantom)

    p = commands.add_parser("report", help="a self-contained HTML report (works offline) and PNG figures")
    p.add_argument("calibration", help="calibration JSON")
    p.add_argument("--recording", help="recording CSV (default: the calibration's own)")
    p.add_argument("--verification", help="verification JSON (from spacecal verify -o)")
    p.add_argument("--png-dir", help="also write PNG figures here")
    p.add_argument("-o", "--output", required=True, help="HTML file to write")
    p.set_defaults(run=_cmd_report)

    p = commands.add_parser(
        "plan", help="plan a calibration motion for the smallest predicted error at the site"
    )
    p.add_argument("--budget", default="30s", help="motion time budget, e.g. 30s (default)")
    p.add_argument("--scenario", help="the (simulated) set-up to plan for (default paper-realistic)")
    p.add_argument("--frames-per-station", type=int, default=5, help="tracker frames held at each station")
    p.add_argument("-o", "--output", help="plan JSON to write")
    p.set_defaults(run=_cmd_plan)

    p = commands.add_parser("scenario", help="print a scenario preset as JSON, to edit")
    p.add_argument("preset", nargs="?", default="paper-realistic")
    p.set_defaults(run=_cmd_scenario)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``spacecal`` console script."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        args.run(args)
    except (SpacecalError, OSError) as exc:
        if args.debug:
            raise
        print(f"spacecal: error: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
