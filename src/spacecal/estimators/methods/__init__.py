"""The calibration methods: each solves ``tracker_from_base`` and ``tcp_from_marker`` from a recording.

A method states the facts of its own fit (the frames it used, their residuals, its covariance
where it has a likelihood); judging the fit is the assessment's (:mod:`spacecal.estimators.assessment`),
which the methods never import, but for the kinematic method's data-driven prior.
"""
