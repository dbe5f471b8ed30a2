"""Orchestration of devices and estimators; devices are reached only through spacecal.core.ports."""
