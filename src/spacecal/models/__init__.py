"""Descriptions of the devices: robot kinematics, tracker measurement volume, marker geometry."""
