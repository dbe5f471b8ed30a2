"""Estimators of ``tracker_from_base`` and ``tcp_from_marker``: one public function, a named registry."""

from spacecal.estimators.registry import ESTIMATORS, EstimatorSpec, Family, Need, calibrate, estimator

__all__ = ["ESTIMATORS", "EstimatorSpec", "Family", "Need", "calibrate", "estimator"]
