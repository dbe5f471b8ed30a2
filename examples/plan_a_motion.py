"""Plan a 20-second calibration motion for the smallest predicted needle-tip error.

    python examples/plan_a_motion.py

The planner picks static stations the tracker can see, within the robot's reach and joint
limits, by how much each reduces the predicted error at the surgical site per second.
"""

import tempfile
from pathlib import Path

from spacecal import app

with tempfile.TemporaryDirectory() as folder:
    planned = app.plan(app.PlanSettings(budget_s=20.0, output=str(Path(folder) / "plan.json")))
    plan, [path] = planned.record, planned.files_written
    print(f"{len(plan.station_joints_rad)} stations, {plan.motion_time_s:.1f} s of motion")
    print(
        f"predicted tip error at the site: {plan.predicted_error_mm:.3f} mm "
        f"(paper's sweeps: {plan.paper_sweep['predicted_error_mm']:.3f} mm in "
        f"{plan.paper_sweep['motion_time_s']:.1f} s)"
    )
    print(f"plan written to {path.name} ({path.stat().st_size} bytes)")
