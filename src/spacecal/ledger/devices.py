"""The record's robots and trackers as the station's operator keeps them: a new one under a
name of its own, edited, retired, or deleted while nothing names it.

A device a calibration names (recorded, or in progress at a station) is never deleted: the
calibration's row points at it. It is retired instead: kept with every value it had, offered
for no new calibration, shown as retired. The functions here take an open transaction; the
:class:`~spacecal.ledger.Ledger` methods check the values first and open it.
"""

from __future__ import annotations

from typing import Any

from spacecal.core.errors import InvalidInputError
from spacecal.core.text import quoted
from spacecal.ledger import schema
from spacecal.ledger.schema import sa

#: The record's kinds of device and their tables.
DEVICE_TABLES = {"robot": schema.robots, "tracker": schema.trackers}


class NameTakenError(InvalidInputError):
    """A robot's or tracker's name another of its kind in the record has (retired ones too:
    a calibration names its devices, and two of one name could not be told apart)."""


class DeviceInUseError(InvalidInputError):
    """A device a calibration names, which the record keeps (retire it instead)."""


def device_table(kind: str) -> sa.Table:
    """The table of ``kind`` (``"robot"`` or ``"tracker"``).

    Raises
    ------
    InvalidInputError
    """
    table = DEVICE_TABLES.get(kind)
    if table is None:
        raise InvalidInputError(f"a device is a robot or a tracker, not {quoted(kind)}")
    return table


def name_taken(connection: sa.Connection, kind: str, name: str, other_than: int | None = None) -> None:
    """Raise :class:`NameTakenError` when another ``kind`` of the record is named ``name``."""
    table = device_table(kind)
    query = sa.select(table.c.id, table.c.retired_utc).where(table.c.name == name)
    if other_than is not None:
        query = query.where(table.c.id != other_than)
    row = connection.execute(query).first()
    if row is not None:
        retired = ", retired," if row.retired_utc else ""
        raise NameTakenError(
            f"the record has a {kind} named {quoted(name, 200)}{retired} already: give this one another name"
        )


def existing(connection: sa.Connection, kind: str, device_id: int) -> dict[str, Any]:
    """The row of ``kind`` ``device_id``.

    Raises
    ------
    InvalidInputError
        No such device in the record.
    """
    table = device_table(kind)
    row = connection.execute(sa.select(table).where(table.c.id == device_id)).first()
    if row is None:
        raise InvalidInputError(f"the record has no {kind} {device_id}")
    return dict(row._mapping)


def uses(connection: sa.Connection, kind: str, device_id: int) -> int:
    """How many calibrations name the device: recorded ones and the station's calibrations in
    progress (``workspaces``)."""
    column = f"{kind}_id"
    count = 0
    for table in (schema.calibrations, schema.workspaces):
        count += int(
            connection.execute(
                sa.select(sa.func.count()).select_from(table).where(table.c[column] == device_id)
            ).scalar_one()
        )
    return count


def delete(connection: sa.Connection, kind: str, device_id: int) -> None:
    """Delete a device no calibration names.

    Raises
    ------
    DeviceInUseError
        A calibration names it (retire it instead).
    """
    row = existing(connection, kind, device_id)
    used = uses(connection, kind, device_id)
    if used:
        raise DeviceInUseError(
            f"{quoted(row['name'], 200)} is named by {used} calibration{'s' if used > 1 else ''}: "
            "the record keeps it; retire it instead"
        )
    table = device_table(kind)
    connection.execute(sa.delete(table).where(table.c.id == device_id))
