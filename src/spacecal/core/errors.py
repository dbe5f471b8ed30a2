"""The package's exceptions.

One root, :class:`SpacecalError`; every subclass also inherits the built-in exception a
caller would expect, so ``except ValueError`` keeps working for code that does not know
spacecal.
"""


class SpacecalError(Exception):
    """Root of every error spacecal raises on purpose."""


class InvalidInputError(SpacecalError, ValueError):
    """Input that is malformed: a missing column, a NaN, a wrong unit, a bad option."""


class DegenerateDataError(SpacecalError, ValueError):
    """Well-formed data that cannot determine the answer (too little rotation, bent lines...)."""


class UnknownMethodError(InvalidInputError):
    """A method name that is not in a registry; the message lists the valid ones."""


class UnreachableError(SpacecalError, ValueError):
    """A pose the robot cannot reach (outside the workspace or the joint limits)."""


class DeviceError(SpacecalError, OSError):
    """A fault reported by, or detected on, a robot or tracker."""


class MissingExtraError(SpacecalError, ImportError):
    """An optional dependency is not installed; the message names the extra."""


class RecordError(SpacecalError, OSError):
    """The calibration record (its database) could not be read or written: locked, damaged,
    unreachable, full; the message says which in one line and never holds a password."""
