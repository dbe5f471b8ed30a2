"""The figures the paper reports, in one place, for side-by-side tables and plots.

Paper §5.2 (verification with a laser tracker, 15 needle poses) and §5.3 (phantom needle
biopsy, Table 2). The paper gives the mean position error as a bound ("< 1.05 mm"), not a
mean: tables print it as such.
"""

from __future__ import annotations

#: §5.2: verification errors of the real UR10 + Polaris Vicra system.
PAPER_VERIFICATION = {
    "position_min_mm": 0.87,
    "position_mean_bound_mm": 1.05,
    "posture_min_deg": 0.83,
    "posture_mean_deg": 1.1,
}

#: §5.3, Table 2: smallest errors of the phantom needle biopsy.
PAPER_PHANTOM = {"entry_min_mm": 0.87, "target_min_mm": 0.83, "direction_min_deg": 0.89}

#: §4: "about one minute" of calibration motion.
PAPER_MOTION_TIME_S = 60.0
