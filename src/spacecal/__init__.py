"""spacecal: calibrate a surgical robot's base frame to an optical tracker.

The package is layered (see ``CONVENTIONS`` in the README): ``frames``, ``units``,
``errors``, ``records`` and ``devices`` at the bottom; ``geometry`` (pure numpy/scipy);
``models`` (robot kinematics, tracker and marker descriptions); ``estimators`` and
``planning``; ``workflows`` and ``io``; ``sim``; and ``cli`` on top.
"""

__version__ = "0.1.0"
