"""Registering an object to the tracker with a tracked pointer: pivot calibration of the pointer's
tip (:mod:`~spacecal.registration.pivot`), detection of the landmarks it touches
(:mod:`~spacecal.registration.landmarks`) and paired-point rigid registration with its error
figures (:mod:`~spacecal.registration.points`).

None of it calibrates the robot to the tracker (that is :mod:`spacecal.estimators`): these solve
the tracker-side problems around it, on the same geometry core.
"""
