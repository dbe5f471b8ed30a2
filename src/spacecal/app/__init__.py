"""The app layer: one typed function per command, taking a settings dataclass and returning
typed records. The command line (:mod:`spacecal.cli`) only parses, calls one of these and
prints; a notebook does exactly what the command line does by calling them.

>>> from spacecal import app
>>> out = app.simulate(app.SimulateSettings(output="rec.csv", scenario="paper-white"))  # doctest: +SKIP
>>> settings = app.CalibrateSettings(recording="rec.csv", output="cal.json", method="ml")
>>> cal = app.calibrate(settings)  # doctest: +SKIP
>>> cal.record.tracker_from_base, cal.files_written, cal.quality  # doctest: +SKIP

Every command returns one shape, :class:`CommandResult`: the typed record, its quality and
provenance where there are such, the files written, notes, and the lines the command line
prints.
"""

from collections.abc import Callable
from typing import Any

from spacecal.app.acquisition import AcquireOutput, AcquireSettings, acquire
from spacecal.app.calibration import (
    TRACKER_KINDS,
    BoundResult,
    BoundSettings,
    CalibrateSettings,
    PivotSettings,
    bound,
    calibrate,
    pivot,
)
from spacecal.app.checking import CheckOutput, CheckSettings, check
from spacecal.app.devices import DeviceSettings, device_url_forms, end_programs_left_running
from spacecal.app.doctor import DoctorOutput, DoctorSettings, doctor, doctor_result
from spacecal.app.files import (
    ExportSettings,
    ImportPlusSettings,
    RegisterLandmarksSettings,
    ReportSettings,
    export,
    import_plus,
    register_landmarks,
    report,
)
from spacecal.app.guidance import GuideOutput, GuideSettings, guide
from spacecal.app.planner import PlanSettings, plan
from spacecal.app.poses import ImportPosesSettings, import_poses
from spacecal.app.record import open_record, record_calibration, record_check
from spacecal.app.result import CommandResult, Quality
from spacecal.app.ros import (
    ImportBagSettings,
    ImportEasyHandeyeSettings,
    RosExportSettings,
    export_calibration,
    export_ros,
    import_bag,
    import_easy_handeye,
)
from spacecal.app.simulation import (
    DEFAULT_SCENARIO,
    DemoSettings,
    PhantomCommandSettings,
    SimulateOutput,
    SimulateSettings,
    demo,
    phantom,
    scenario,
    simulate,
)
from spacecal.app.slicer_plan import PlanFromSlicerSettings, plan_from_slicer
from spacecal.app.verification import VerifySettings, verify
from spacecal.estimators import ESTIMATORS
from spacecal.records.assessment import ErrorThresholds
from spacecal.report.live import DEFAULT_PORT as LIVE_VIEW_PORT

#: The estimators ``calibrate`` takes by name (``CalibrateSettings.method``).
ESTIMATOR_NAMES = tuple(sorted(ESTIMATORS))

#: Every command, by its command-line name: each returns a :class:`CommandResult`.
COMMANDS: dict[str, Callable[..., CommandResult[Any]]] = {
    "simulate": simulate,
    "calibrate": calibrate,
    "pivot": pivot,
    "bound": bound,
    "verify": verify,
    "demo": demo,
    "acquire": acquire,
    "doctor": doctor,
    "register-landmarks": register_landmarks,
    "export": export_calibration,
    "import-plus": import_plus,
    "import-bag": import_bag,
    "import-easy-handeye": import_easy_handeye,
    "import-poses": import_poses,
    "check": check,
    "phantom": phantom,
    "report": report,
    "plan": plan,
    "plan-from-slicer": plan_from_slicer,
    "guide": guide,
    "scenario": scenario,
}

__all__ = [
    "COMMANDS",
    "DEFAULT_SCENARIO",
    "ESTIMATOR_NAMES",
    "LIVE_VIEW_PORT",
    "TRACKER_KINDS",
    "AcquireOutput",
    "AcquireSettings",
    "BoundResult",
    "BoundSettings",
    "CalibrateSettings",
    "CheckOutput",
    "CheckSettings",
    "CommandResult",
    "DemoSettings",
    "DeviceSettings",
    "DoctorOutput",
    "DoctorSettings",
    "ErrorThresholds",
    "ExportSettings",
    "GuideOutput",
    "GuideSettings",
    "ImportBagSettings",
    "ImportEasyHandeyeSettings",
    "ImportPlusSettings",
    "ImportPosesSettings",
    "Quality",
    "RosExportSettings",
    "PhantomCommandSettings",
    "PivotSettings",
    "PlanFromSlicerSettings",
    "PlanSettings",
    "RegisterLandmarksSettings",
    "ReportSettings",
    "SimulateOutput",
    "SimulateSettings",
    "VerifySettings",
    "acquire",
    "bound",
    "calibrate",
    "check",
    "demo",
    "device_url_forms",
    "doctor",
    "doctor_result",
    "end_programs_left_running",
    "export",
    "export_calibration",
    "export_ros",
    "guide",
    "import_bag",
    "import_easy_handeye",
    "import_plus",
    "import_poses",
    "open_record",
    "record_calibration",
    "record_check",
    "phantom",
    "pivot",
    "plan",
    "plan_from_slicer",
    "register_landmarks",
    "report",
    "scenario",
    "simulate",
    "verify",
]
