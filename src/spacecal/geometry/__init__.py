"""Pure numpy/scipy geometry: transforms, rotations, fitting, error metrics."""
