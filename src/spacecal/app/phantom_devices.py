"""``spacecal phantom --robot sim --tracker sim``: the paper's phantom needle biopsy (§5.3,
Table 2) run on the simulated devices through the commands a user runs on hardware.

The steps, each an app function writing its files into the work folder as the command line
would:

1. the calibration: ``--calibration`` if given, else ``acquire`` on the devices
   (the paired recording) and ``calibrate`` (``calibration.json``);
2. the CT scan: the simulated phantom (:attr:`spacecal.sim.world.World.phantom`) written as
   3D Slicer writes it: its fiducials as a point list with the CT's localisation error
   (:attr:`spacecal.experiments.phantom.PhantomSettings.ct_error_mm`, ``ct_fiducials.mrk.json``)
   and each case's planned path as a Line, entry then target, in LPS (``plan_K.mrk.json``);
3. ``touch``: the simulated hand puts the pointer on each fiducial (``touched.csv``), the
   pointer-made registration;
4. ``guide`` for each case (stage ``all``, insertion ``advance``, the CT fiducials and the
   touches): the needle placed and measured by the calibrated marker (``guidance_K.json``);
5. the second CT: the needle where it truly is (the simulator's truth the guidance carries,
   :attr:`spacecal.records.guidance.StageMeasurement.simulated_true_tracker_from_needle`)
   mapped into the image and localised with the CT's error
   (:func:`spacecal.experiments.phantom.second_ct_errors`): the entry, target and direction
   errors of Table 2.

Every device call opens the simulated world of one scenario, written once as
``scenario.json`` and passed to ``touch`` and ``guide`` (the calibration's own world), so the
phantom, the touches and the needle are of one world. Real devices are refused: there the
second CT is a real scan, which spacecal cannot take.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from spacecal.app._common import guard_outputs, open_calibration, scenario_of_calibration
from spacecal.app.acquire_settings import AcquireSettings
from spacecal.app.acquisition import acquire
from spacecal.app.calibration import CalibrateSettings, calibrate
from spacecal.app.devices import DeviceSettings
from spacecal.app.guidance import GuideSettings, guide
from spacecal.app.phantom_settings import PhantomCommandSettings, check_devices
from spacecal.app.touch import TouchCommandSettings, touch
from spacecal.core.errors import SpacecalError
from spacecal.experiments.phantom import PhantomSettings, second_ct_errors
from spacecal.geometry.transforms import invert_transform
from spacecal.io.recording_files import paired_files, recording_in
from spacecal.io.results_json import write_json
from spacecal.io.slicer_markups import write_markups
from spacecal.records import PhantomResult
from spacecal.records.guidance import GuidanceResult
from spacecal.sim.scenario import load_scenario
from spacecal.sim.world import build_world

#: The random stream of the CT's localisation errors (both scans), apart from the world's.
CT_STREAM = 53
#: Says where the second CT's needle comes from, in the output and the result.
SECOND_CT = "the second CT: the simulator's true needle, localised with the CT's error"


def work_folder(settings: PhantomCommandSettings) -> tuple[Path, bool]:
    """The work folder (``--work-dir``; else ``OUTPUT_STEM.work`` beside ``-o``; else a new
    temporary folder, kept) and whether it was made here."""
    if settings.work_dir is not None:
        return Path(settings.work_dir), False
    if settings.output is not None:
        output = Path(settings.output)
        return output.with_name(output.name.removesuffix(output.suffix) + ".work"), False
    return Path(tempfile.mkdtemp(prefix="spacecal-phantom-")), True


def work_files(cases: int, calibrating: bool) -> list[str]:
    """The files the steps write into the work folder."""
    return [
        *(
            [*(path.name for path in paired_files(recording_in("."))), "calibration.json"]
            if calibrating
            else []
        ),
        "scenario.json",
        "ct_fiducials.mrk.json",
        "touched.csv",
        *(f"plan_{k + 1}.mrk.json" for k in range(cases)),
        *(f"guidance_{k + 1}.json" for k in range(cases)),
    ]


def phantom_on_devices(settings: PhantomCommandSettings) -> tuple[PhantomResult, list[str]]:
    """Run the phantom experiment on the simulated devices (module docstring).

    Returns
    -------
    PhantomResult
        Per case the second CT's errors, guide's reported ones and the predicted ones.
    list of str
        A line per step (what it wrote).

    Raises
    ------
    InvalidInputError
        Bad input, or a file of the work folder that exists (without ``--force``).
    SpacecalError
        A step failed (its own one line).
    """
    check_devices(settings)
    work, made = work_folder(settings)
    calibrating = settings.calibration is None
    guard_outputs(
        [settings.output, settings.figure, *(work / n for n in work_files(settings.cases, calibrating))],
        [settings.calibration],
        settings.force,
        any_file=True,
    )
    work.mkdir(parents=True, exist_ok=True)
    devices = DeviceSettings(settings.robot, settings.tracker)
    lines = [f"work folder: {work}" + (" (made for this run, kept)" if made else "")]

    # 1. the calibration
    if calibrating:
        recording = recording_in(work)
        acquired = acquire(
            AcquireSettings(output=str(recording), devices=devices, scenario=settings.scenario)
        )
        calibration_path = work / "calibration.json"
        calibrate(CalibrateSettings(str(recording), output=str(calibration_path), method=settings.method))
        run = acquired.record.result
        samples = "" if run is None else f" ({run.samples_written} samples)"
        lines.append(
            f"1. calibration: acquire -> {recording.name}{samples}, calibrate --method {settings.method} "
            f"-> {calibration_path.name}"
        )
    else:
        calibration_path = Path(str(settings.calibration))
        lines.append(f"1. calibration: {calibration_path}")
    calibration, notes = open_calibration(calibration_path, "phantom", None)
    lines += [f"   note: {note}" for note in notes]
    scenario = scenario_of_calibration(calibration)[0] or load_scenario(settings.scenario)
    scenario_file = write_json(scenario.to_dict(), work / "scenario.json")

    # 2. the CT scan
    world = build_world(scenario)
    phantom = world.phantom
    ct_error_mm = PhantomSettings.ct_error_mm
    rng = np.random.default_rng([scenario.seed, CT_STREAM])
    seen = {
        label: point + rng.normal(scale=ct_error_mm / np.sqrt(3.0), size=3)
        for label, point in phantom.fiducials_in_image.items()
    }
    fiducials = write_markups(work / "ct_fiducials.mrk.json", seen, kind="Fiducial", name="CT fiducials")
    plans = [
        write_markups(
            work / f"plan_{k + 1}.mrk.json",
            {"entry": path.entry_in_image, "target": path.target_in_image},
            kind="Line",
            name=path.label,
        )
        for k, path in enumerate(phantom.paths[: settings.cases])
    ]
    lines.append(
        f"2. CT scan: {len(seen)} fiducials ({ct_error_mm:g} mm RMS localisation error) -> {fiducials.name}; "
        f"{len(plans)} planned paths -> plan_1..{len(plans)}.mrk.json (Slicer Lines, LPS)"
    )

    # 3. the pointer's touches: the registration
    touched_path = work / "touched.csv"
    touched = touch(
        TouchCommandSettings(
            fiducials=str(fiducials),
            output=str(touched_path),
            tracker=str(settings.tracker),
            scenario=str(scenario_file),
            force=settings.force,
        )
    ).record
    pointer = touched.registration.pointer
    assert pointer is not None  # a pointer registration
    lines.append(
        f"3. touch: {len(touched.touched_in_tracker)} fiducials touched -> {touched_path.name}; "
        f"registration FRE {pointer.fre_rms_mm:.3f} mm RMS"
    )

    # 4. guide each case; 5. the second CT
    image_from_tracker = invert_transform(phantom.tracker_from_image)
    errors, predicted, reported = [], [], []
    for k, plan in enumerate(plans):
        output = work / f"guidance_{k + 1}.json"
        guidance = guide(
            GuideSettings(
                plan=str(plan),
                calibration=str(calibration_path),
                fiducials=str(fiducials),
                touched=str(touched_path),
                devices=devices,
                scenario=str(scenario_file),
                stage="all",
                insertion="advance",
                output=str(output),
                force=settings.force,
            )
        ).record.result
        assert guidance is not None  # not a dry run
        errors.append(_second_ct(guidance, image_from_tracker, ct_error_mm, rng))
        predicted.append(
            {
                "entry_mm": guidance.predicted_entry_error_mm,
                "target_mm": guidance.predicted_target_error_mm,
                "direction_deg": guidance.predicted_direction_error_deg,
                "contributions": dict(guidance.predicted_contributions),
            }
        )
        reported.append(
            {
                "entry_mm": guidance.entry_error_mm,
                "target_mm": guidance.target_error_mm,
                "direction_deg": guidance.direction_error_deg,
                "measured_by": guidance.measured_by,
                "guidance": output.name,
                "plan": plan.name,
            }
        )
    lines.append(
        f"4. guide: {len(plans)} cases (stage all, insertion advance) -> guidance_1..{len(plans)}.json"
    )
    lines.append(f"5. {SECOND_CT} ({ct_error_mm:g} mm RMS)")
    entry, target, direction = (np.array(column) for column in zip(*errors))
    result = PhantomResult(
        entry,
        target,
        direction,
        predicted,
        pointer.fre_rms_mm,
        calibration.method,
        0,
        reported=reported,
        devices={
            "robot": str(settings.robot),
            "tracker": str(settings.tracker),
            "scenario": scenario.name,
            "work_dir": str(work),
            "calibration": str(calibration_path),
            "measured_by": SECOND_CT,
        },
    )
    return result, lines


def _second_ct(
    guidance: GuidanceResult, image_from_tracker: np.ndarray, ct_error_mm: float, rng: np.random.Generator
) -> tuple[float, float, float]:
    """The second CT's entry, target and direction errors of the needle the guidance left in."""
    last = guidance.last
    truth = None if last is None else last.simulated_true_tracker_from_needle
    if last is None or last.stage != "insert" or truth is None:
        raise SpacecalError(
            f"guidance of {guidance.plan_name} did not end inserted with the simulator's truth of its needle"
        )
    return second_ct_errors(
        image_from_tracker @ truth, guidance.entry_in_image, guidance.target_in_image, ct_error_mm, rng
    )


__all__ = ["CT_STREAM", "SECOND_CT", "phantom_on_devices", "work_files", "work_folder"]
