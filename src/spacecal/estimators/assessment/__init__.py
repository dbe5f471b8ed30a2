"""The assessment of a calibration: its uncertainty, the error to expect at a target, the verdict.

It judges what a method solved (:mod:`spacecal.estimators.methods`) and may import the methods
(their ML information and refits are its instruments); no method imports it, but for the
kinematic method's data-driven prior (see ``pyproject.toml``'s import contracts).
"""
