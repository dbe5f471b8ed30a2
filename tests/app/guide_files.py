"""Files as 3D Slicer writes them for a simulated world's phantom: the needle plan (a markups
Line or point list, in LPS or RAS) and the image registration (an ITK ``.tfm``), and the
pointer's touches of the phantom's fiducials; the guide tests on the simulated devices and on
the protocol fakes share them.

Conventions (the sources the project's readers follow, :mod:`spacecal.io.slicer_markups` and
:mod:`spacecal.io.slicer`): a markups file states ``coordinateSystem`` ``LPS`` or ``RAS`` and
``coordinateUnits`` ``mm`` (markups schema v1.0.3); ``RAS = diag(-1, -1, 1) LPS``; a Slicer
transform node ``TrackerToRAS`` saved as ``.tfm`` holds ITK's from-parent (resampling)
transform in LPS, and its to-parent matrix is ``image_ras_from_tracker``.
"""

import json

import numpy as np

from spacecal.geometry.transforms import invert_transform
from spacecal.io import slicer_markups
from spacecal.io.slicer import write_slicer_transform
from spacecal.io.touched_points import write_touched_points
from spacecal.sim.devices import SimulatedRobot, SimulatedTracker
from spacecal.sim.tools import POINTER, POINTER_TIP_ERROR_MM
from spacecal.workflows.pointer_touches import TouchSettings, collect_touches, touched_points

LPS = np.diag([-1.0, -1.0, 1.0, 1.0])


def write_markups(path, points, kind="Line", system="LPS", units="mm", drop_system=False):
    """A markups file of ``points`` ({label: position in image_lps, mm}) as Slicer saves it
    (:func:`spacecal.io.slicer_markups.write_markups`: a ``Line`` labelled L-1, L-2, entry then
    target, or a labelled point list ``Fiducial``), its positions in ``system``; ``system`` and
    ``units`` are written as given (a bad one for the readers' tests), ``drop_system`` leaves the
    coordinate system out as other software does."""
    if system not in ("LPS", "RAS"):
        slicer_markups.write_markups(path, points, kind, "LPS", units=units)
        data = json.loads(path.read_text())
        data["markups"][0]["coordinateSystem"] = system
    else:
        slicer_markups.write_markups(path, points, kind, system, units=units)
        data = json.loads(path.read_text())
    if drop_system:
        del data["markups"][0]["coordinateSystem"]
    path.write_text(json.dumps(data, indent=4))
    return path


def write_plan(path, world, which=0, kind="Line", system="LPS"):
    """Phantom path ``which`` as a Slicer plan file; returns (path, the path)."""
    planned = world.phantom.paths[which]
    points = {"entry": planned.entry_in_image, "target": planned.target_in_image}
    return write_markups(path, points, kind, system), planned


def write_registration(path, tracker_from_image_lps):
    """The registration as Slicer saves the transform node TrackerToRAS (.tfm)."""
    return write_slicer_transform(LPS @ invert_transform(tracker_from_image_lps), path)


def write_pointer_registration(folder, world, robot=None):
    """The phantom's fiducials (a point list, LPS) and the simulated pointer's touches of them
    (:func:`collect_touches`, the tip as the pointer's calibration has it)."""
    phantom = world.phantom
    fiducials = write_markups(folder / "fiducials.mrk.json", phantom.fiducials_in_image, kind="Fiducial")
    tracker = SimulatedTracker(world, robot or SimulatedRobot(world), tools=(POINTER,))
    touches = collect_touches(
        tracker,
        POINTER,
        world.pointer_from_tip,
        phantom.labels,
        world.place_pointer,
        TouchSettings(wait_s=3.0),
    )
    world.put_pointer_away()
    # with the simulated pointer's stated tip accuracy, as ``spacecal touch`` writes it
    touched = write_touched_points(
        folder / "touched.csv",
        touched_points(touches),
        comments=["simulated"],
        tip_accuracy_mm=POINTER_TIP_ERROR_MM,
    )
    return fiducials, touched


def make_calibration(folder):
    """A calibration of the default simulated world (simulate, then the ML fit), as a user makes one."""
    from spacecal import app

    recording = folder / "rec.csv"
    app.simulate(app.SimulateSettings(output=str(recording)))
    path = folder / "cal.json"
    app.calibrate(app.CalibrateSettings(str(recording), output=str(path), method="ml"))
    return path
