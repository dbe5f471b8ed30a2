"""How a robot's published positioning figures translate into the error models we simulate and plan with."""

from __future__ import annotations

#: Per-axis s.d. of the TCP position scatter per mm of ISO 9283 pose repeatability.
#:
#: ISO 9283 repeatability RP = mean + 3 s.d. of the 3-D distance from the mean position.
#: For isotropic Gaussian scatter with per-axis s.d. s that distance follows a Maxwell
#: distribution with mean 1.60 s and s.d. 0.67 s, so RP is about 1.60 s + 3 * 0.67 s = 3.6 s.
REPEATABILITY_TO_AXIS_SD = 1.0 / 3.6

#: ISO 9283 pose repeatability (mm) of Universal Robots arms, from their datasheets: CB3
#: (UR3, UR5, UR10) +-0.1 mm (UR10/CB3 User Manual, technical specifications); e-Series
#: +-0.03 mm (UR3e, UR5e) and +-0.05 mm (UR10e, UR16e) ("pose repeatability per ISO 9283",
#: e-Series technical specifications).
UR_REPEATABILITY_MM = {
    "UR3": 0.1,
    "UR5": 0.1,
    "UR10": 0.1,
    "UR3e": 0.03,
    "UR5e": 0.03,
    "UR10e": 0.05,
    "UR16e": 0.05,
}
