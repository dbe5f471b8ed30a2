"""The record of every robot, tracker, tool, calibration and check a site has made.

An embedded SQLite file by default; a site with several stations points them at one
PostgreSQL server instead (any SQLAlchemy URL). Needs the ``station`` extra (SQLAlchemy, and
psycopg for PostgreSQL); importing this package without it raises
:class:`~spacecal.core.errors.MissingExtraError` naming the extra.

>>> from spacecal.ledger import Ledger
>>> ledger = Ledger.open("sqlite:///record.db")  # doctest: +SKIP
>>> ledger.record_calibration(calibration, "cal.json", source="cli")  # doctest: +SKIP
"""

from spacecal.ledger.devices import DeviceInUseError, NameTakenError
from spacecal.ledger.store import (
    SIMULATED_ROBOT,
    SIMULATED_TRACKER,
    CalibrationRow,
    CheckRow,
    Ledger,
    ledger_url,
    redacted_url,
)

__all__ = [
    "SIMULATED_ROBOT",
    "SIMULATED_TRACKER",
    "CalibrationRow",
    "CheckRow",
    "DeviceInUseError",
    "Ledger",
    "NameTakenError",
    "ledger_url",
    "redacted_url",
]
