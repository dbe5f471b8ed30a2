"""The values a person gives for a device, checked in one place for every way they come in:
the command line's options, the station's forms and the record.

The messages are in an operator's words and name no option: the station shows them beside the
form's field, the record raises them as they are, and the command line puts its option's name
in front (:func:`spacecal.app.devices.check_tracker_rate_hz`). The robot's model is checked
beside the kinematic tables it names (:func:`spacecal.models.robot_kinds.check_robot_kind`), the
device address by the parser that opens the device
(:func:`spacecal.app.devices.validate_device_url`).
"""

from __future__ import annotations

import math

from spacecal.core.errors import InvalidInputError
from spacecal.core.strict_numbers import parse_float
from spacecal.core.text import quoted

#: Tracker frame rates spacecal accepts, Hz (a Polaris Vicra runs at 20, a Vega at 60; an
#: OpenIGTLink or NatNet server may stream up to several hundred).
TRACKER_RATE_RANGE_HZ = (1.0, 1000.0)


def _range_words() -> str:
    low, high = TRACKER_RATE_RANGE_HZ
    return f"from {low:g} to {high:g} frames per second"


def check_frame_rate(rate_hz: object, shown: str | None = None) -> float:
    """``rate_hz`` as a float if it is a tracker frame rate spacecal accepts: a finite number in
    :data:`TRACKER_RATE_RANGE_HZ`, Hz. ``shown`` is the value as the person typed it, for the
    message (default: the number).

    Raises
    ------
    InvalidInputError
        One line in an operator's words ("the frame rate must be from 1 to 1000 frames per
        second, not -20").
    """
    if isinstance(rate_hz, bool) or not isinstance(rate_hz, (int, float)):
        raise InvalidInputError(f"the frame rate must be a number {_range_words()}, not {quoted(rate_hz)}")
    low, high = TRACKER_RATE_RANGE_HZ
    if not (math.isfinite(rate_hz) and low <= rate_hz <= high):
        raise InvalidInputError(f"the frame rate must be {_range_words()}, not {shown or f'{rate_hz:g}'}")
    return float(rate_hz)


def frame_rate_from_text(text: str) -> float | None:
    """A frame rate typed into a form (Hz), checked as :func:`check_frame_rate` checks it; None
    for an empty field (the tracker's own rate is then taken: 20 Hz).

    Numbers are read as spacecal reads every number typed or written
    (:func:`spacecal.core.strict_numbers.parse_float`: ``1_000`` or ``٢٠`` is no number).

    Raises
    ------
    InvalidInputError
        Not a number, or out of range; the text entered is shown as typed.
    """
    stripped = text.strip()
    if not stripped:
        return None
    try:
        value = parse_float(stripped)
    except ValueError:
        raise InvalidInputError(
            f"the frame rate must be a number {_range_words()}, not {quoted(stripped, 40)}"
        ) from None
    return check_frame_rate(value, quoted(stripped, 40))
