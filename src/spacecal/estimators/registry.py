"""The registry of calibration methods, chosen by name."""

from __future__ import annotations

import inspect
from typing import Callable

from ..errors import InvalidInputError, UnknownMethodError
from ..records import CalibrationResult, Recording
from .closed_form import HAND_EYE_SOLVERS, ROBOT_WORLD_SOLVERS, hand_eye_method, robot_world_method
from .likelihood import calibrate_ml, calibrate_robust
from .paper import calibrate_paper

#: name -> function(recording, **options) -> CalibrationResult
METHODS: dict[str, Callable[..., CalibrationResult]] = {
    "paper": calibrate_paper,
    "ml": calibrate_ml,
    "robust": calibrate_robust,
    **{name: robot_world_method(name) for name in ROBOT_WORLD_SOLVERS},
    **{name: hand_eye_method(name) for name in HAND_EYE_SOLVERS},
}


def calibrate(recording: Recording, method: str = "paper", **options) -> CalibrationResult:
    """Estimate ``tracker_from_base`` and ``tcp_from_marker`` from a recording.

    Parameters
    ----------
    recording : Recording
    method : str
        A name from :data:`METHODS`.
    **options
        Passed to the method.

    Raises
    ------
    UnknownMethodError
        For a name not in the registry; the message lists the valid ones.
    """
    if method not in METHODS:
        raise UnknownMethodError(f"unknown method {method!r}; valid methods: {', '.join(sorted(METHODS))}")
    accepted = inspect.signature(METHODS[method]).parameters
    unexpected = sorted(set(options) - set(accepted))
    if unexpected:
        takers = sorted(m for m, f in METHODS.items() if set(unexpected) <= set(inspect.signature(f).parameters))
        raise InvalidInputError(f"method {method!r} does not take {', '.join(unexpected)}"
                                + (f" (methods that do: {', '.join(takers)})" if takers else ""))
    return METHODS[method](recording, **options)
