"""spacecal: calibrate a surgical robot's base frame to an optical tracker.

The package is layered (docs/conventions.md); each layer imports only from those below it:
``core`` (frames, units, errors, device ports); ``geometry``; ``models`` (robot kinematics,
tracker and marker); ``records`` (typed results); ``estimators`` (robot-to-tracker calibration),
``registration`` (pivot calibration, landmarks, paired points) and ``planning``; ``io``;
``workflows``, ``sim`` and ``adapters`` (independent peers); ``experiments`` and ``report``;
``app`` (one typed function per command); and ``cli`` on top.
"""

__version__ = "0.1.0"
