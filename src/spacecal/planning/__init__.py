"""Calibration motion planning: the paper's sweeps (§4), time parametrisation, feasibility."""
