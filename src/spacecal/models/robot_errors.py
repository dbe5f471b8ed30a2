"""How a robot's published positioning figures translate into the error models we simulate and plan with."""

from __future__ import annotations

#: Per-axis s.d. of the TCP position scatter per mm of ISO 9283 pose repeatability.
#:
#: ISO 9283 repeatability RP = mean + 3 s.d. of the 3-D distance from the mean position.
#: For isotropic Gaussian scatter with per-axis s.d. s that distance follows a Maxwell
#: distribution with mean 1.60 s and s.d. 0.67 s, so RP is about 1.60 s + 3 * 0.67 s = 3.6 s.
REPEATABILITY_TO_AXIS_SD = 1.0 / 3.6

#: The datasheet repeatability of each arm is its robot kind's ``repeatability_mm``
#: (:mod:`spacecal.models.robot_kinds`).
