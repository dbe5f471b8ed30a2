"""Export a calibration to 3D Slicer and PLUS.

    python examples/export_to_slicer.py

Slicer loads the ``.tfm`` file as a linear transform named BaseToTracker (its matrix is
``tracker_from_base``, converted to Slicer's LPS/resampling convention in the file); PLUS
reads the CoordinateDefinitions XML.
"""

import tempfile
from pathlib import Path

from spacecal import app
from spacecal.io.slicer import read_slicer_transform

with tempfile.TemporaryDirectory() as folder:
    folder = Path(folder)
    app.simulate(app.SimulateSettings(str(folder / "rec.csv"), scenario="paper-white"))
    calibrated = app.calibrate(app.CalibrateSettings(str(folder / "rec.csv"), str(folder / "cal.json"), "ml"))
    for line in app.export(
        app.ExportSettings(
            str(folder / "cal.json"), slicer=str(folder / "BaseToTracker.tfm"), plus=str(folder / "plus.xml")
        )
    ).lines:
        print(line)
    read_back = read_slicer_transform(folder / "BaseToTracker.tfm")
    difference = abs(read_back - calibrated.record.tracker_from_base).max()
    print(f"the Slicer file reads back to tracker_from_base within {difference:.1e} mm")
