"""The calibration station: the whole calibration workflow in a web browser, for the people at
the robot (``spacecal station``; needs the ``station`` extra).

It drives the same :mod:`spacecal.app` functions the command line calls, keeps every
calibration and check in the record (:mod:`spacecal.ledger`), and never starts a motion
without a confirmation that names the robot and the motion. See ``docs/station.md``.
"""
