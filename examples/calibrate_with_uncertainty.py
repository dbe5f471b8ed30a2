"""Calibrate a recording by maximum likelihood and read its uncertainty.

    python examples/calibrate_with_uncertainty.py [recording.csv]

Without an argument a recording is simulated first. The result carries a 12x12 covariance
of the two transforms and the predicted target registration error (TRE) at the surgical
site and at any target you name (points in the robot base frame, mm).
"""

import sys
import tempfile
from pathlib import Path

import numpy as np

from spacecal import app

with tempfile.TemporaryDirectory() as folder:
    if len(sys.argv) > 1:
        recording = sys.argv[1]
    else:
        recording = str(Path(folder) / "recording.csv")
        app.simulate(app.SimulateSettings(recording, scenario="paper-white"))
    out = app.calibrate(
        app.CalibrateSettings(
            recording,
            str(Path(folder) / "calibration.json"),
            "ml",
            targets_in_base=((-573.0, -164.0, 338.0),),
        )
    )
    calibration = out.record
    sd = np.sqrt(np.diag(np.asarray(calibration.covariance["matrix"])))
    print("tracker_from_base (mm):")
    print(np.array2string(calibration.tracker_from_base, precision=3, suppress_small=True))
    print("parameter standard deviations:")
    for name, value in zip(calibration.covariance["parameters"], sd):
        # rotation parameters are stored in rad and shown in deg, under their name without the unit
        if name.endswith("_rad"):
            print(f"  {name.removesuffix('_rad'):28s} {np.degrees(value):.4f} deg")
        else:
            print(f"  {name.removesuffix('_mm'):28s} {value:.4f} mm")
    tre = calibration.predicted_tre_mm
    print(
        f"predicted TRE at the site {tre['site']:.3f} mm; at the target {tre['targets'][0]['tre_mm']:.3f} mm"
    )
    print(f"verdict: {calibration.verdict.text if calibration.verdict else 'none'}")
