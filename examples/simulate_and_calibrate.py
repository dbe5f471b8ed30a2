"""Simulate the paper's calibration run and calibrate it from Python, as the command line does.

    python examples/simulate_and_calibrate.py

Runs in about ten seconds on the simulated UR10 + Polaris Vicra (white tracker noise).
"""

import dataclasses
import tempfile
from pathlib import Path

from spacecal import app
from spacecal.experiments.truth import calibration_error
from spacecal.sim.scenario import load_scenario
from spacecal.sim.world import build_world

with tempfile.TemporaryDirectory() as folder:
    recording = str(Path(folder) / "recording.csv")
    simulated = app.simulate(app.SimulateSettings(recording, scenario="paper-white", seed=2)).record
    print(f"simulated {simulated.samples} samples ({simulated.visible} with the marker seen)")

    for method in ("paper", "ml"):
        out = app.calibrate(app.CalibrateSettings(recording, str(Path(folder) / f"{method}.json"), method))
        # the simulator knows the truth: score the calibration against it
        world = build_world(dataclasses.replace(load_scenario("paper-white"), seed=2))
        error = calibration_error(out.record, world)
        print(f"{method:>5}: TRE over a 200 mm cube {error['tre_rms_mm']:.3f} mm RMS")
