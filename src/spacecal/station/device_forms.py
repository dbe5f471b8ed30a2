"""The home page's robot and tracker forms: each field checked by the check the command line
and the record use, its message kept for the field it belongs to, and the values entered kept
for the form shown again.

The checks are spacecal's own, in an operator's words (no option names, no Python messages):
the address by the parser that opens the device
(:func:`spacecal.app.devices.validate_device_url`), the name by
:func:`spacecal.core.text.check_name`, the robot's model by
:func:`spacecal.models.robot_kinds.check_robot_kind` and the frame rate by
:func:`spacecal.core.device_fields.frame_rate_from_text`; the record checks the same again.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from spacecal.app.devices import validate_device_url
from spacecal.core.device_fields import frame_rate_from_text
from spacecal.core.errors import InvalidInputError
from spacecal.core.text import check_name, exception_line
from spacecal.models.robot_kinds import check_robot_kind

#: The fields of each kind's form, in the order they are shown.
FIELDS = {"robot": ("name", "url", "model"), "tracker": ("name", "url", "rate_hz")}
#: What an empty address field asks for (it never silently becomes the simulated device).
NO_ADDRESS = {
    "robot": "give the robot's address: ur://HOST, or sim for the simulated robot",
    "tracker": "give the tracker's address: ndi://PORT_OR_HOST, igtl://HOST:PORT, "
    "natnet://HOST?body=BODY, or sim for the simulated tracker",
}
#: Longest value taken from a field, characters (the body is bounded at 64 kB by the doors; an
#: address is at most 500 characters, a name 200).
FIELD_LIMIT = 1000
#: Longest value kept to show again in a form, characters.
SHOWN_LIMIT = 300


@dataclass
class DeviceForm:
    """A robot's or tracker's form as it was submitted, with a message for each field refused.

    Attributes
    ----------
    kind : {"robot", "tracker"}
    device_id : int or None
        The device edited; None for a new one.
    entered : dict of str to str
        Each field's text as entered (cut to :data:`SHOWN_LIMIT`), to show the form again.
    errors : dict of str to str
        The message for each field refused, one line each.
    """

    kind: str
    device_id: int | None = None
    entered: dict[str, str] = field(default_factory=dict)
    errors: dict[str, str] = field(default_factory=dict)
    name: str = ""
    url: str = ""
    model: str | None = None
    rate_hz: float | None = None

    @property
    def form_id(self) -> str:
        """The form's element id on the home page (and the address's fragment)."""
        return f"add-{self.kind}" if self.device_id is None else f"edit-{self.kind}-{self.device_id}"

    def refuse(self, key: str, exc: BaseException | str) -> None:
        """Keep the first message for field ``key``."""
        self.errors.setdefault(key, exc if isinstance(exc, str) else exception_line(exc))

    def value(self, key: str, default: Any = "") -> Any:
        """The text a field shows: what was entered."""
        return self.entered.get(key, default)


def _text(form: Any, key: str) -> str:
    value = form.get(key, "")
    if not isinstance(value, str):
        raise InvalidInputError("give text here, not a file")
    if len(value) > FIELD_LIMIT:
        raise InvalidInputError(f"this is longer than {FIELD_LIMIT} characters")
    return value.strip()


def read_device_form(form: Any, kind: str, device_id: int | None = None) -> DeviceForm:
    """The form of a ``kind`` device, each field checked; :attr:`DeviceForm.errors` is empty
    when every value was taken.

    Raises
    ------
    InvalidInputError
        ``kind`` is neither a robot nor a tracker.
    """
    if kind not in FIELDS:
        raise InvalidInputError("add a robot or a tracker")
    out = DeviceForm(kind, device_id)
    texts = {}
    for key in FIELDS[kind]:
        raw = form.get(key, "")
        out.entered[key] = raw[:SHOWN_LIMIT] if isinstance(raw, str) else ""
        try:
            texts[key] = _text(form, key)
        except InvalidInputError as exc:
            out.refuse(key, exc)
    if "name" in texts:
        if not texts["name"]:
            out.refuse("name", f"give the {kind} a name")
        else:
            try:
                out.name = check_name(texts["name"], "the name")
            except InvalidInputError as exc:
                out.refuse("name", exc)
    if "url" in texts:
        if not texts["url"]:
            out.refuse("url", NO_ADDRESS[kind])
        else:
            try:
                out.url = validate_device_url(kind, texts["url"])
            except InvalidInputError as exc:
                out.refuse("url", exc)
    if texts.get("model"):
        try:
            out.model = check_robot_kind(texts["model"])
        except InvalidInputError as exc:
            out.refuse("model", exc)
    if "rate_hz" in texts:
        try:
            out.rate_hz = frame_rate_from_text(texts["rate_hz"])
        except InvalidInputError as exc:
            out.refuse("rate_hz", exc)
    return out


def entered_from_row(kind: str, row: dict[str, Any]) -> dict[str, str]:
    """A device's fields as its edit form shows them, from its record row."""
    rate = row.get("rate_hz")
    values = {"name": row["name"], "url": row["url"]}
    if kind == "robot":
        values["model"] = row.get("model") or ""
    else:
        values["rate_hz"] = "" if rate is None else f"{rate:g}"
    return values


def default_device(rows: list[dict[str, Any]]) -> int | None:
    """The device a new calibration's list starts on: the one in service added last (the
    highest id). Adding a device never moves the default to another one than the device just
    added (the one the operator is about to calibrate), however its name sorts; retiring
    another leaves it where it is."""
    in_service = [row["id"] for row in rows if not row.get("retired_utc")]
    return max(in_service) if in_service else None
