"""Estimators of ``tracker_from_base`` and ``tcp_from_marker``: one public function, a named registry."""

from spacecal.estimators.registry import METHODS, calibrate

__all__ = ["METHODS", "calibrate"]
