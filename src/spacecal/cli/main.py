"""The ``spacecal`` command line: parse, call one app function, print.

Every default comes from the app's settings dataclasses, so none is written twice. Exit
codes: 0 success; 1 a known error, printed as one line (``--debug`` shows the traceback);
2 a usage error.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import signal
import sys
import threading
import warnings
from typing import Any

from spacecal import app
from spacecal.app.devices import finding_line
from spacecal.cli import parser
from spacecal.core import interrupts
from spacecal.core.errors import InvalidInputError, MissingExtraError, SpacecalError
from spacecal.core.text import sanitize_for_terminal
from spacecal.estimators.diagnostics import ErrorThresholds

#: Longest error, note or finding line printed (text from files and devices is cut there).
ERROR_CHARS = 2000


class CheckFailed(SpacecalError):
    """A calibration check did not pass (exit code 1, like any known failure)."""


def _numbers(text: str, count: int, option: str, what: str) -> Any:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != count:
        raise InvalidInputError(f"{option} takes {what}, got {text!r}")
    return values


def _points(texts: list[str] | None, option: str = "--target") -> Any:
    return tuple(_numbers(t, 3, option, "x,y,z in mm") for t in texts or [])


def _seconds(seconds: float) -> float:
    if seconds <= 0:
        raise InvalidInputError(f"--budget must be positive, got {seconds:g} s")
    return seconds


def _print_notes(messages: list[str]) -> None:
    for message in messages:
        print(f"note: {sanitize_for_terminal(message, ERROR_CHARS)}")


# -- commands -------------------------------------------------------------------------------
def _simulate(a: argparse.Namespace) -> None:
    out = app.simulate(
        app.SimulateSettings(a.output, a.scenario, a.seed, a.raw, a.clock_offset_ms, a.force, plan=a.plan)
    )
    if a.raw:
        print(
            f"wrote {out.paths[0]} ({out.robot_states} robot states) and {out.paths[1]} "
            f"({out.samples} tracker frames); robot clock {out.clock_offset_ms} ms ahead (simulated)"
        )
        return
    print(
        f"wrote {out.paths[0]} ({out.samples} samples, {out.visible} with the marker visible) "
        f"and {out.paths[1]}"
    )
    print(
        f"simulated: scenario {out.scenario}, seed {out.seed}; planned motion time {out.motion_time_s:.1f} s"
    )
    if out.gate is not None:
        print(out.gate.summary())
    _print_notes(out.messages)


def _calibrate(a: argparse.Namespace) -> None:
    offset = None
    if a.time_offset_ms != "estimate":
        try:
            offset = float(a.time_offset_ms)
        except ValueError:
            raise InvalidInputError("--time-offset-ms takes a number or 'estimate'") from None
    ledger = app.open_record(a.record) if a.record else None
    out = app.calibrate(
        app.CalibrateSettings(
            a.recording,
            a.output,
            a.method,
            a.tracker_stream,
            offset,
            _points(a.target),
            a.sigma_mm,
            ErrorThresholds.parse(a.thresholds_mm) if a.thresholds_mm else None,
            a.force,
            include_doubtful_frames=a.include_doubtful_frames,
            tracker_kind=a.tracker_kind,
        )
    )
    if ledger is not None:
        app.record_calibration(ledger, out, source="cli")
        ledger.close()
    if out.time_offset_note:
        print(out.time_offset_note)
    if out.doubtful_note:
        print(out.doubtful_note)
    _print_notes(out.notes)
    result = out.calibration
    counts, d = result.sample_counts, result.diagnostics
    print(f"wrote {out.path} (method {result.method}; {counts['used']} of {counts['total']} samples used)")
    if d.get("sphere"):
        lines = ", ".join(
            f"{sanitize_for_terminal(k, 60)} {v['straightness_rms_mm']:.3f} mm" for k, v in d["lines"].items()
        )  # segment labels come from the recording file
        print(
            f"sphere: radius {d['sphere']['radius_mm']:.2f} mm, fit RMS {d['sphere']['rms_mm']:.3f} mm; "
            f"line straightness RMS: {lines}"
        )
    if "residual_position_rms_mm" in d:
        # a kinematic calibration places the TCP with the kinematics it identified, as the
        # report does; the line says which, so the two are read as the same quantity
        tcp = "identified robot kinematics" if result.robot_model is not None else "recorded TCP poses"
        print(
            f"marker residuals (RMS, {tcp}): position {d['residual_position_rms_mm']:.3f} mm, "
            f"rotation {d['residual_rotation_rms_deg']:.3f} deg"
        )
    if result.predicted_tre_mm:
        tre = result.predicted_tre_mm
        print(
            f"predicted TRE: {tre['site']:.3f} mm at the site, {tre['cube_rms']:.3f} mm RMS over a "
            f"{tre['cube_side_mm']:.0f} mm cube around it"
        )
        for target in tre.get("targets", []):
            print(f"  at {target['target_in_base_mm']}: {target['tre_mm']:.3f} mm")
    if "outliers" in d:
        print(f"outliers: {len(d['outliers'])} frames flagged (listed in the result file)")
    if "position_mm" in d.get("expected_error", {}):
        e = d["expected_error"]
        print(
            f"expected error at a target near the site: {e['position_mm']:.2f} mm, {e['posture_deg']:.2f} deg"
        )
    judged = result.verdict
    if judged is not None:
        print(f"verdict: {judged.text}")
        if not judged.usable:
            raise CheckFailed(f"calibration unusable (written to {out.path}): {'; '.join(judged.reasons)}")


def _bound(a: argparse.Namespace) -> None:
    bound = app.bound(app.BoundSettings(a.recording, a.calibration, a.sigma_mm, _points(a.target)))
    _print_notes(bound["notes"])
    print(
        f"Cramer-Rao lower bound on TRE for {a.recording} with {bound['sigma_mm']:.3g} mm per-axis sphere "
        f"noise ({bound['sigma_source']}):"
    )
    print(
        f"  {bound['site']:.4f} mm at the site, {bound['cube_rms']:.4f} mm RMS over a "
        f"{bound['cube_side_mm']:.0f} mm cube around it"
    )
    for target in bound.get("targets", []):
        print(f"  at {target['target_in_base_mm']}: {target['tre_mm']:.4f} mm")


def _pivot(a: argparse.Namespace) -> None:
    result, path = app.pivot(app.PivotSettings(a.poses, a.method, a.subset, a.output, a.force))
    summary = result.to_dict()
    if path:
        print(f"wrote {path}")
    print(f"pivot calibration ({result.method}, {summary['frames']} frames)")
    print("  tip in marker   (mm): " + ", ".join(f"{v:.3f}" for v in result.tip_in_marker))
    print("  pivot in tracker (mm): " + ", ".join(f"{v:.3f}" for v in result.pivot_in_tracker))
    print(
        f"  residual: RMS {result.rms_mm:.3f} mm (3-D), {result.rms_per_axis_mm:.3f} mm per axis "
        f"(scikit-surgerycalibration's figure), mean {summary['residual_mean_mm']:.3f}, "
        f"max {summary['residual_max_mm']:.3f} mm"
    )


def _verify(a: argparse.Namespace) -> None:
    out = app.verify(app.VerifySettings(a.calibration, a.scenario, a.points, a.output, a.figure, a.force))
    for path in out.paths:
        print(f"wrote {path}")
    _print_notes(out.notes)
    s = out.result.statistics()
    pos, ang = s["position_mm"], s["posture_deg"]
    print(
        f"verification in simulation on {len(out.result.position_error_mm)} needle poses "
        f"(scenario {out.scenario}, from {out.world_source}):"
    )
    print(
        f"  position error min / mean / max / RMS: {pos['min']:.3f} / {pos['mean']:.3f} / "
        f"{pos['max']:.3f} / {pos['rms']:.3f} mm   (paper: min 0.87, mean < 1.05 mm)"
    )
    print(
        f"  posture error  min / mean / max / RMS: {ang['min']:.3f} / {ang['mean']:.3f} / "
        f"{ang['max']:.3f} / {ang['rms']:.3f} deg  (paper: min 0.83, mean about 1.1 deg)"
    )


def _demo(a: argparse.Namespace) -> None:
    out = app.demo(app.DemoSettings(a.scenario, a.out, a.force))
    print(out.result.table())
    if out.paths:
        print(f"\nwrote {', '.join(p.name for p in out.paths)} to {a.out}")


def _progress(total_moves: int):
    """A one-line progress display on stderr: bar, move, samples, markers seen."""
    tty = sys.stderr.isatty()

    def show(samples: int, visible: int, move_index: int, label: str) -> None:
        if samples % (10 if tty else 100):
            return
        done = int(30 * (move_index + 1) / max(1, total_moves))
        print(
            f"[{'#' * done}{'.' * (30 - done)}] move {move_index + 1}/{total_moves} "
            f"{sanitize_for_terminal(label, 40):8s} samples "  # a plan file names the moves
            f"{samples} (marker seen {visible})",
            end="\r" if tty else "\n",
            file=sys.stderr,
            flush=True,
        )

    return show


def _tool(a: argparse.Namespace) -> Any:
    """``--tool controller`` (None) or X,Y,Z,RX,RY,RZ; ``--tool-offset-mm X,Y,Z`` is X,Y,Z,0,0,0."""
    if a.tool is not None and a.tool_offset_mm is not None:
        raise InvalidInputError("give --tool or --tool-offset-mm, not both")
    if a.tool_offset_mm is not None:
        return (*_numbers(a.tool_offset_mm, 3, "--tool-offset-mm", "x,y,z in mm"), 0.0, 0.0, 0.0)
    if a.tool is None or a.tool.strip().lower() == "controller":
        return None
    return _numbers(a.tool, 6, "--tool", "controller or X,Y,Z,RX,RY,RZ (mm, rotation vector in rad)")


def _devices(a: argparse.Namespace) -> app.DeviceSettings:
    """The devices ``acquire``, ``check`` and ``doctor`` name, from their shared flags."""
    return app.DeviceSettings(
        a.robot, a.tracker, tuple(a.rom or ()), a.tracker_rate_hz, a.robot_model, _tool(a)
    )


def _workspace_box(a: argparse.Namespace) -> Any:
    if not a.workspace_box:
        return None
    return _numbers(a.workspace_box, 6, "--workspace-box", "xmin,xmax,ymin,ymax,zmin,zmax in mm")


def _doctor(a: argparse.Namespace) -> None:
    out = app.doctor(app.DoctorSettings(_devices(a)))
    for device, finding in out.findings:
        print(sanitize_for_terminal(finding_line(device, finding), ERROR_CHARS))  # devices name things
    if out.problems:
        count = len(out.problems)
        raise CheckFailed(
            f"{count} problem{'s' if count > 1 else ''} found (marked PROBLEM above); fix "
            f"{'them' if count > 1 else 'it'} before running spacecal acquire"
        )
    print("every check passed: spacecal acquire can start")


def _acquire(a: argparse.Namespace) -> None:
    settings = app.AcquireSettings(
        a.output,
        devices=_devices(a),
        scenario=a.scenario,
        dry_run=a.dry_run,
        resume=a.resume,
        confirm_robot_motion=a.confirm_robot_motion,
        speed_mm_s=a.speed_mm_s,
        accel_mm_s2=a.accel_mm_s2,
        angular_speed_deg_s=a.angular_speed_deg_s,
        workspace_box=_workspace_box(a),
        prior=a.prior,
        rotation_deg=a.rotation_deg,
        translation_mm=a.translation_mm,
        plan=a.plan,
        stop_and_go=a.stop_and_go,
    )
    holder: dict[str, int] = {}
    view = None
    if a.live_view is not None and not a.dry_run:
        from spacecal.report.live import LiveView

        view = LiveView(a.live_view)
        if view.start():
            print(f"live view: {view.url} (open it in a web browser)", flush=True)
        else:
            view = None
    try:
        out = app.acquire(
            settings,
            on_sample=lambda *sample: _progress(holder.get("moves", 1))(*sample),
            observer=view.observe if view is not None else None,
            on_plan=lambda moves: holder.update(moves=moves),
        )
    finally:
        if view is not None:
            view.close()
    print(
        f"plan: {out.moves} moves, {out.motion_time_s:.1f} s of motion"
        + (" (simulated devices, simulated time)" if out.simulated else "")
    )
    _print_notes(out.messages)
    if out.dry_run:
        for line in out.gate.lines() if out.gate is not None else []:
            print(line)
        print("dry run: nothing moved")
        return
    if out.gate is not None:
        print(out.gate.summary())
    r = out.result
    assert r is not None
    print(
        f"\nwrote {r.recording_path}: {r.samples_written} samples, {r.visible_written} with the marker seen; "
        f"{r.moves_completed}/{r.moves_total} moves"
    )


def _register_landmarks(a: argparse.Namespace) -> None:
    result, times, path = app.register_landmarks(
        app.RegisterLandmarksSettings(
            a.sequence, a.config, a.reference, a.stylus, a.plus_compatible, a.output, a.force
        )
    )
    if path:
        print(f"wrote {path}")
    print(
        f"registered {len(result.residuals_mm)} landmarks (detected at "
        + ", ".join(f"{t - times[0]:.1f}" for t in result.detected_at_s)
        + " s)"
    )
    print("reference_from_phantom:")
    for row in result.reference_from_phantom:
        print("  " + "  ".join(f"{v:11.6f}" for v in row))
    print(
        f"landmark error: mean {result.fre_mean_mm:.3f} mm (PLUS's 'Error'), RMS {result.fre_rms_mm:.3f} mm; "
        "per landmark " + ", ".join(f"{v:.2f}" for v in result.residuals_mm)
    )


def _export(a: argparse.Namespace) -> None:
    ros = (a.easy_handeye2, a.ros2_launch, a.urdf, a.static_tf, a.ur_calibration)
    lines = []
    ros_settings = app.RosExportSettings(
        a.calibration,
        *ros,
        a.base_frame,
        a.tool_frame,
        a.tracker_frame,
        a.marker_frame,
        a.force,
        a.accept_edited,
    )
    if any(ros):
        # every ROS file checked before anything is written: a refused name or model leaves
        # no Slicer or PLUS file behind either
        app.export_ros(ros_settings, write=False)
    if a.slicer or a.plus or a.igtl or not any(ros):
        lines += app.export(
            app.ExportSettings(a.calibration, a.slicer, a.plus, a.igtl, a.force, a.accept_edited)
        )
    if any(ros):
        lines += app.export_ros(ros_settings)
    for line in dict.fromkeys(lines):  # a note on the calibration is made by both exports
        print(sanitize_for_terminal(line, ERROR_CHARS))  # names from the calibration and paths


def _import_bag(a: argparse.Namespace) -> None:
    print(
        app.import_bag(
            app.ImportBagSettings(
                a.bag,
                a.output,
                a.list,
                a.base_frame,
                a.tool_frame,
                a.tracker_frame,
                a.marker_frame,
                a.joint_states,
                a.marker_topic,
                a.robot_model,
                a.force,
            )
        )
    )


def _import_poses(a: argparse.Namespace) -> None:
    out = app.import_poses(
        app.ImportPosesSettings(a.robot, a.tracker, a.output, a.units, a.eye_in_hand, a.force)
    )
    raw = out.raw
    print(
        f"wrote {out.robot_path} ({len(raw.robot_time_s)} robot poses) and {out.tracker_path} "
        f"({len(raw.tracker_time_s)} tracker poses{', eye-in-hand' if a.eye_in_hand else ''}); calibrate "
        f"with: spacecal calibrate {out.robot_path} --tracker-stream {out.tracker_path} --method ml"
    )
    _print_notes(list(out.notes))


def _import_easy_handeye(a: argparse.Namespace) -> None:
    print(app.import_easy_handeye(a.samples, a.output, a.force))


def _import_plus(a: argparse.Namespace) -> None:
    path, frames, visible = app.import_plus(
        app.ImportPlusSettings(a.sequence, a.output, a.marker, a.tcp, a.segment, a.force)
    )
    print(f"wrote {path}: {frames} frames, {visible} with the marker seen")


def _check(a: argparse.Namespace) -> None:
    ledger = app.open_record(a.record) if a.record else None
    out = app.check(
        app.CheckSettings(
            a.calibration,
            a.recording,
            devices=_devices(a),
            scenario=a.scenario,
            poses=a.poses,
            threshold_mm=a.threshold_mm,
            threshold_deg=a.threshold_deg,
            dry_run=a.dry_run,
            confirm_robot_motion=a.confirm_robot_motion,
            workspace_box=_workspace_box(a),
            frames_per_pose=a.frames_per_pose,
            accept_edited=a.accept_edited,
            accept_other_devices=a.accept_other_devices,
        )
    )
    if out.gate is not None:
        # a dry run (no result) shows every check; a run that moved, the verdict
        for line in out.gate.lines() if out.result is None else [out.gate.summary()]:
            print(line)
    _print_notes(out.messages)
    if ledger is not None:
        app.record_check(ledger, a.calibration, out, source="cli")
        ledger.close()
    r = out.result
    if r is None:
        return
    for k, (label, error, angle) in enumerate(zip(r.labels, r.tcp_error_mm, r.rotation_error_deg)):
        label = sanitize_for_terminal(label, 60)
        if r.misfit_mm is None or r.expected_misfit_mm is None or r.tolerance_mm is None:
            print(f"  {label:>10}: TCP {error:.3f} mm, rotation {angle:.3f} deg")
            continue
        assert r.misfit_deg is not None and r.expected_misfit_deg is not None and r.tolerance_deg is not None
        print(
            f"  {label:>10}: TCP {math.hypot(*r.misfit_mm[k]):.3f} mm off "
            f"({math.hypot(*r.expected_misfit_mm[k]):.3f} expected), departs {error:.3f} mm "
            f"(tolerance {r.tolerance_mm[k]:.2f}); rotation {math.hypot(*r.misfit_deg[k]):.3f} deg "
            f"({math.hypot(*r.expected_misfit_deg[k]):.3f} expected), departs {angle:.3f} deg "
            f"(tolerance {r.tolerance_deg[k]:.2f})"
        )
    where = {True: "simulated robot and tracker", False: "real robot and tracker", None: "recording"}[
        r.simulated
    ]
    limits = "tolerances up to" if r.has_expectations else "thresholds"
    print(
        f"{'PASS' if r.passed else 'FAIL'} ({where}): {limits} {r.threshold_mm:.2f} mm and "
        f"{r.threshold_deg:.2f} deg, {out.threshold_basis} (history: {out.history})"
    )
    if not r.passed:
        raise CheckFailed("the calibration no longer holds: recalibrate (marker bumped, tracker moved?)")


def _phantom(a: argparse.Namespace) -> None:
    from spacecal.experiments.phantom import phantom_table

    result, paths = app.phantom(
        app.PhantomCommandSettings(a.scenario, a.method, a.cases, a.output, a.figure, a.force)
    )
    print(phantom_table(result))
    print(
        "(simulated; measured errors include the second CT's localisation error, as in the paper's "
        "experiment)"
    )
    for path in paths:
        print(f"wrote {path}")


def _report(a: argparse.Namespace) -> None:
    out = app.report(
        app.ReportSettings(
            a.calibration, a.output, a.recording, a.verification, a.png_dir, a.force, a.accept_edited
        )
    )
    print(f"wrote {out.path} ({len(out.titles)} plots: {', '.join(out.titles)})")
    if out.figures:
        print(f"wrote {len(out.figures)} PNG figures: {', '.join(str(p) for p in out.figures)}")
    _print_notes(out.notes)


def _plan(a: argparse.Namespace) -> None:
    record, path = app.plan(
        app.PlanSettings(
            _seconds(a.budget),
            a.scenario,
            a.frames_per_station,
            _numbers(a.site, 3, "--site", "x,y,z in mm") if a.site else None,
            a.paper_sweeps,
            a.output,
            a.force,
            needle_path_mm=_numbers(a.needle_path, 6, "--needle-path", "entry x,y,z and target x,y,z in mm")
            if a.needle_path
            else None,
        )
    )
    site = (
        "the TCP at home"
        if record.site_in_base is None
        else "(" + ", ".join(f"{v:.1f}" for v in record.site_in_base) + ") mm"
    )
    if record.kind == "paper-sweeps":
        print(
            f"the paper's sweeps for the simulated set-up {a.scenario}: {len(record.moves)} moves, "
            f"{record.motion_time_s:.1f} s of motion, predicted tip error at {site} "
            f"{record.predicted_error_mm:.3f} mm"
        )
    else:
        print(
            f"planned for the simulated set-up {a.scenario}: {len(record.station_joints_rad)} stations, "
            f"{record.motion_time_s:.1f} s of motion, predicted tip error at {site} "
            f"{record.predicted_error_mm:.3f} mm"
        )
        print(
            f"paper's sweeps: {record.paper_sweep['motion_time_s']:.1f} s of motion, predicted tip error "
            f"there {record.paper_sweep['predicted_error_mm']:.3f} mm"
        )
    print(
        "(predicted for a joint fit of the calibration and the robot's DH corrections: "
        "spacecal calibrate --method kinematic)"
    )
    if path:
        print(f"wrote {path}; run it with: spacecal acquire --plan {path} ... (or simulate --plan)")


def _station(a: argparse.Namespace) -> None:
    try:
        from spacecal.station.server import StationOptions, serve
    except ImportError as exc:
        raise MissingExtraError(
            "spacecal station needs the station extra: pip install 'spacecal[station]'"
        ) from exc
    serve(
        StationOptions(
            host=a.host,
            port=a.port,
            token=a.token,
            data=a.data,
            record=a.record,
            open=a.open,
            simulated=a.simulated,
        )
    )


def _scenario(a: argparse.Namespace) -> None:
    print(json.dumps(app.scenario(a.preset), indent=2))


COMMANDS = {
    "simulate": _simulate,
    "calibrate": _calibrate,
    "pivot": _pivot,
    "bound": _bound,
    "verify": _verify,
    "demo": _demo,
    "acquire": _acquire,
    "doctor": _doctor,
    "register-landmarks": _register_landmarks,
    "export": _export,
    "import-plus": _import_plus,
    "import-bag": _import_bag,
    "import-easy-handeye": _import_easy_handeye,
    "import-poses": _import_poses,
    "check": _check,
    "phantom": _phantom,
    "report": _report,
    "plan": _plan,
    "scenario": _scenario,
    "station": _station,
}


def build_parser() -> argparse.ArgumentParser:
    """The ``spacecal`` argument parser."""
    return parser.build_parser(COMMANDS)


def _raise_interrupt(signum, frame) -> None:
    reason = "Ctrl-C" if signum == signal.SIGINT else signal.Signals(signum).name
    if not interrupts.request_stop(reason):
        # a second signal while the run stops (Ctrl-C pressed twice, a service manager's
        # repeated SIGTERM) must not abort the robot's stop half-way: it is ignored
        return
    raise interrupts.StopRequested(reason)


def _unraisable(hook):
    """``sys.unraisablehook`` that stays quiet about a stop request Python could not raise (it
    landed in a weakref callback or a ``__del__``): the request is kept, and the loop moving the
    robot raises it at its next frame (:mod:`spacecal.core.interrupts`)."""

    def quiet(unraisable) -> None:
        if not isinstance(unraisable.exc_value, interrupts.StopRequested):
            hook(unraisable)

    return quiet


@contextlib.contextmanager
def _signals_as_interrupts():
    """SIGINT, SIGTERM and SIGHUP raise KeyboardInterrupt once while a command runs (main
    thread only), and the request is kept until the run has seen it; later ones are ignored
    until the command has cleaned up."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    interrupts.clear()
    previous = {}
    for name in ("SIGINT", "SIGTERM", "SIGHUP"):
        number = getattr(signal, name, None)
        if number is not None:
            previous[number] = signal.signal(number, _raise_interrupt)
    previous_hook = sys.unraisablehook
    sys.unraisablehook = _unraisable(previous_hook)
    try:
        yield
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)
        sys.unraisablehook = previous_hook
        interrupts.clear()  # the command has stopped and cleaned up: the request is spent


def _signal_named(exc: BaseException, text: str) -> str:
    """A run stopped by SIGTERM or SIGHUP says so (the acquisition names every interruption
    Ctrl-C)."""
    cause = exc.__context__
    if isinstance(cause, interrupts.StopRequested) and cause.args and cause.args[0] != "Ctrl-C":
        return text.replace("interrupted by the user (Ctrl-C)", f"interrupted ({cause.args[0]})")
    return text


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``spacecal`` console script.

    Exit codes: 0 success; 1 a known error, an interruption (Ctrl-C, SIGTERM, SIGHUP) or an
    internal error, each printed as one line (``--debug`` shows the traceback); 2 a usage
    error (argparse's message: an unknown option, a missing value, a value that does not
    parse as the option's type).
    """
    args = build_parser().parse_args(parser.join_negative_coordinates(sys.argv[1:] if argv is None else argv))
    try:
        with _signals_as_interrupts(), warnings.catch_warnings():
            if not args.debug:
                # the one-line error says what went wrong; library warnings (numpy's overflow
                # notes, an empty file) would only add lines to it
                warnings.simplefilter("ignore")
            args.run(args)
    except (SpacecalError, OSError) as exc:
        if args.debug:
            raise
        print(f"spacecal: error: {_signal_named(exc, _one_line(exc))}", file=sys.stderr)
        return 1
    except KeyboardInterrupt as exc:
        if args.debug:
            raise
        what = exc.args[0] if isinstance(exc, interrupts.StopRequested) and exc.args else "Ctrl-C"
        # the same words as an interruption the acquisition catches itself
        who = "interrupted by the user" if what == "Ctrl-C" else "interrupted"
        print(f"spacecal: error: {who} ({what}); every file written is complete", file=sys.stderr)
        return 1
    except RecursionError:
        if args.debug:
            raise
        print("spacecal: error: input nested too deeply", file=sys.stderr)
        return 1
    except Exception as exc:
        if args.debug:
            raise
        print(
            f"spacecal: internal error: {type(exc).__name__}: {_one_line(exc)} "
            "(please report it; --debug shows the traceback)",
            file=sys.stderr,
        )
        return 1
    return 0


def _one_line(exc: BaseException) -> str:
    """The error as one bounded line whose control characters are escaped (a message may quote
    names from files, bags and devices)."""
    return sanitize_for_terminal(" ".join(str(exc).split()), ERROR_CHARS) or type(exc).__name__


def console_main() -> None:
    """The console script: :func:`main`, then the exit. After a dropped robot connection the
    robot library's own threads may still be reconnecting (and may upload their program to
    the controller again); everything of ours is closed and written by then, so the program
    is stopped once more and the process ends at once, without the interpreter's teardown,
    which would destroy the library's objects under those threads (a crash instead of exit
    code 1)."""
    code = main()
    ur = sys.modules.get("spacecal.adapters.ur")
    if ur is not None and ur.interfaces_left_running():
        sys.stdout.flush()
        sys.stderr.flush()
        ur.end_programs_left_running()
        os._exit(code)
    sys.exit(code)


if __name__ == "__main__":
    console_main()
