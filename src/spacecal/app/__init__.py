"""The app layer: one typed function per command, taking a settings dataclass and returning
typed records. The command line (:mod:`spacecal.cli`) only parses, calls one of these and
prints; a notebook does exactly what the command line does by calling them.

>>> from spacecal import app
>>> out = app.simulate(app.SimulateSettings(output="rec.csv", scenario="paper-white"))  # doctest: +SKIP
>>> settings = app.CalibrateSettings(recording="rec.csv", output="cal.json", method="ml")
>>> cal = app.calibrate(settings)  # doctest: +SKIP
"""

from spacecal.app.acquisition import (
    AcquireOutput,
    AcquireSettings,
    CheckOutput,
    CheckSettings,
    PlanSettings,
    acquire,
    check,
    plan,
)
from spacecal.app.calibration import (
    TRACKER_KINDS,
    BoundSettings,
    CalibrateOutput,
    CalibrateSettings,
    PivotSettings,
    bound,
    calibrate,
    pivot,
)
from spacecal.app.devices import DeviceSettings
from spacecal.app.doctor import DoctorOutput, DoctorSettings, doctor
from spacecal.app.files import (
    ExportSettings,
    ImportPlusSettings,
    RegisterLandmarksSettings,
    ReportOutput,
    ReportSettings,
    export,
    import_plus,
    register_landmarks,
    report,
)
from spacecal.app.poses import ImportPosesOutput, ImportPosesSettings, import_poses
from spacecal.app.record import open_record, record_calibration, record_check
from spacecal.app.ros import (
    ImportBagSettings,
    RosExportSettings,
    export_ros,
    import_bag,
    import_easy_handeye,
)
from spacecal.app.simulation import (
    DemoOutput,
    DemoSettings,
    PhantomCommandSettings,
    SimulateOutput,
    SimulateSettings,
    VerifyOutput,
    VerifySettings,
    demo,
    phantom,
    scenario,
    simulate,
    verify,
)

__all__ = [
    "TRACKER_KINDS",
    "AcquireOutput",
    "AcquireSettings",
    "BoundSettings",
    "CalibrateOutput",
    "CalibrateSettings",
    "CheckOutput",
    "CheckSettings",
    "DemoOutput",
    "DemoSettings",
    "DeviceSettings",
    "DoctorOutput",
    "DoctorSettings",
    "ExportSettings",
    "ImportBagSettings",
    "ImportPlusSettings",
    "ImportPosesOutput",
    "ImportPosesSettings",
    "RosExportSettings",
    "PhantomCommandSettings",
    "PivotSettings",
    "PlanSettings",
    "RegisterLandmarksSettings",
    "ReportOutput",
    "ReportSettings",
    "SimulateOutput",
    "SimulateSettings",
    "VerifyOutput",
    "VerifySettings",
    "acquire",
    "bound",
    "calibrate",
    "check",
    "demo",
    "doctor",
    "export",
    "export_ros",
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
    "register_landmarks",
    "report",
    "scenario",
    "simulate",
    "verify",
]
