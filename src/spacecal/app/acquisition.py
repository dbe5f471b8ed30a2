"""App function ``acquire``: run the calibration motion on a robot while sampling the tracker.

The devices (``sim``: the simulated robot and tracker of a scenario, in simulated time; URLs:
hardware adapters, ``ur://HOST``, ``ndi://PORT_OR_HOST``, ``igtl://HOST:PORT``) are opened,
checked, gated, confirmed and closed by the motion session every moving command shares
(:mod:`spacecal.app.motion_session`); this module plans the calibration motion and says what
its recording keeps.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from spacecal.app._common import open_calibration, refuse_overwriting_inputs
from spacecal.app.acquire_settings import AcquireSettings
from spacecal.app.devices import HardwareModel, device_identity, marker_in_use
from spacecal.app.gate import acquisition_gate, approach_line, resumed_move
from spacecal.app.motion_session import motion_session
from spacecal.app.result import CommandResult, note_lines
from spacecal.app.run_plan import hardware_plan, planned_motion
from spacecal.io.recordings import last_time_s, raw_stream_paths
from spacecal.planning.motion_gate import MotionGateReport
from spacecal.planning.stop_and_go import stop_and_go_plan
from spacecal.records import robot_model_to_dict
from spacecal.sim.motion import plan_for_world, recording_metadata
from spacecal.workflows.acquisition import AcquisitionResult, FrameObserver, SampleCallback

__all__ = ["AcquireOutput", "AcquireSettings", "acquire", "acquire_result", "hardware_metadata"]


@dataclass
class AcquireOutput:
    """The plan that was checked or run and, unless a dry run, the acquisition's result."""

    moves: int
    motion_time_s: float
    dry_run: bool = False
    result: AcquisitionResult | None = None
    simulated: bool = True
    #: What the motion gate checked before anything moved (None: nothing was left to run).
    gate: MotionGateReport | None = None
    #: A resumed run: the move back onto the plan it makes first (see ``app.gate.approach_line``).
    approach: str | None = None


def hardware_metadata(
    settings: AcquireSettings, hardware: HardwareModel, robot: object, tracker: object
) -> dict[str, Any]:
    """Metadata of a recording made on real devices: the robot's model as it was used, and
    what each device says it is (serial number, firmware), so that a calibration names the one
    robot and tracker it belongs to."""
    model = hardware.model
    robot_identity = device_identity(robot)
    return {
        "robot": {
            "model": model.name,
            "url": settings.devices.robot,
            **{key: robot_identity[key] for key in ("serial", "firmware") if key in robot_identity},
            "flange_from_tcp": model.flange_from_tcp.tolist(),
            **(
                {"kinematic_model": robot_model_to_dict(model)}
                if hardware.published
                else {"identify_kinematics_from_poses": True}
            ),
            "kinematics_source": hardware.source,
        },
        "tracker": {
            "url": settings.devices.tracker,
            "rate_hz": settings.devices.tracker_rate_hz,
            **device_identity(tracker),
        },
        "marker": marker_in_use(settings.devices.rom),
        "units": {"length": "mm", "angle": "rad", "time": "s"},
        "source": "spacecal acquire",
        "simulated": False,
    }


def _known(hardware: HardwareModel | None) -> HardwareModel:
    assert hardware is not None  # set for every hardware run
    return hardware


def acquire(
    settings: AcquireSettings,
    on_sample: SampleCallback | None = None,
    observer: FrameObserver | None = None,
    on_plan: Callable[[int], None] | None = None,
    on_line: Callable[[str], None] | None = None,
) -> CommandResult[AcquireOutput]:
    """Plan, check and (unless a dry run) run the calibration motion, writing the recording.

    Parameters
    ----------
    settings : AcquireSettings
    on_sample : callable, optional
        Progress callback ``on_sample(samples, visible, move_index, label)``.
    on_plan : callable, optional
        Called with the number of moves once the plan is made (a progress display's total).
    observer : FrameObserver, optional
        Sees every tracker frame, e.g. ``LiveView(...).observe`` of
        :mod:`spacecal.report.live`; it must return at once, and a failing one is detached
        with a warning. ``settings.live_view`` opens such a view itself.
    on_line : callable, optional
        Called with each line to show at once while the command runs (where the live view is).

    Returns
    -------
    CommandResult of AcquireOutput
        The plan checked or run and, unless a dry run, the acquisition's result; the recording
        and raw streams written.
    """
    view = None
    if settings.live_view is not None and not settings.dry_run:
        from spacecal.report.live import LiveView

        view = LiveView(settings.live_view)
        if view.start():
            if on_line is not None:
                on_line(f"live view: {view.url} (open it in a web browser)")
            observer = view.observe
        else:
            view = None
    try:
        output, notes = _acquire(settings, on_sample, observer, on_plan)
    finally:
        if view is not None:
            view.close()
    return acquire_result(output, notes)


def acquire_result(output: AcquireOutput, notes: tuple[str, ...] = ()) -> CommandResult[AcquireOutput]:
    """The result of ``acquire`` from what it planned and ran, and its notes (the dry run's
    device checks, the plan's messages)."""
    lines = [
        f"plan: {output.moves} moves, {output.motion_time_s:.1f} s of motion"
        + (" (simulated devices, simulated time)" if output.simulated else ""),
        *note_lines(notes),
        *([output.approach] if output.approach else []),
    ]
    files: tuple[Path, ...] = ()
    if output.dry_run:
        lines += [*(output.gate.lines() if output.gate is not None else []), "dry run: nothing moved"]
    else:
        if output.gate is not None:
            lines.append(output.gate.summary())
        r = output.result
        assert r is not None
        files = (r.recording_path, *(r.raw_paths or ()))
        lines += [
            "",
            f"wrote {r.recording_path}: {r.samples_written} samples, {r.visible_written} with the marker "
            f"seen; {r.moves_completed}/{r.moves_total} moves",
        ]
    return CommandResult(output, files, notes, tuple(lines))


def _acquire(
    settings: AcquireSettings,
    on_sample: SampleCallback | None,
    observer: FrameObserver | None,
    on_plan: Callable[[int], None] | None,
) -> tuple[AcquireOutput, tuple[str, ...]]:
    # the recording itself: the acquisition refuses an existing one unless resuming it
    refuse_overwriting_inputs(
        settings.output,
        settings.prior,
        settings.scenario,
        settings.plan,
        *settings.devices.rom,
        recordings=False,
    )
    if settings.prior:
        open_calibration(settings.prior, "acquire --prior")  # refused before any device is opened
    # a resumed simulated run continues the recording's time (a real clock just goes on)
    last = last_time_s(raw_stream_paths(settings.output)[0]) if settings.resume else None
    motion = settings.motion(0.0 if last is None else float(np.ceil(last + 1.0)))
    with motion_session(motion) as session:
        world = session.world
        checks = session.device_lines() if settings.dry_run else []
        if settings.dry_run:
            session.refuse_tracker_problem(checks)
        model = session.model
        if settings.plan is not None:
            plan = planned_motion(settings, session.robot, model)
        elif world is not None:
            plan = plan_for_world(world)
        else:
            plan = hardware_plan(settings, session.robot, model)
        limits = motion.limits()
        if settings.stop_and_go:
            plan = stop_and_go_plan(plan, model, limits, session.frame_period_s, settings.stop_and_go)
        if on_plan is not None:
            on_plan(len(plan.moves))
        state = session.robot.state()
        gate = acquisition_gate(settings, plan, model, state, limits, world)
        output = AcquireOutput(len(plan.moves), plan.motion_time_s, simulated=world is not None, gate=gate)
        resumed = resumed_move(settings, plan)
        if gate is not None and resumed is not None:
            # a stop mid-move left the arm between two poses of the plan: the run first moves
            # back onto it (the gate checked that move with the rest)
            output.approach = approach_line(plan, resumed, state.base_from_tcp, limits)
        notes = (*checks, *plan.messages)
        if settings.dry_run:
            output.dry_run = True
            return output, notes
        metadata = (
            recording_metadata(world)
            if world is not None
            else hardware_metadata(settings, _known(session.hardware), session.robot, session.tracker)
        )
        for role, name in (
            ("robot", settings.devices.robot_name),
            ("tracker", settings.devices.tracker_name),
        ):
            if name is not None and isinstance(metadata.get(role), dict):
                metadata[role]["station_name"] = name
        metadata["sampling"] = (
            {
                "mode": "stop-and-go",
                "frames_per_station": settings.stop_and_go,
                "frame_period_s": session.frame_period_s,
            }
            if settings.stop_and_go
            else {"mode": "continuous"}
        )
        metadata["plan"] = {
            **plan.summary(),
            "file": None if settings.plan is None else str(Path(settings.plan).resolve()),
            "motion_gate": None if gate is None else gate.to_dict(),
        }
        session.begin_motion(output.approach)
        output.result = session.record(
            plan, settings.output, metadata, resume=settings.resume, on_sample=on_sample, observer=observer
        )
        return output, notes
