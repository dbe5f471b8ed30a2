"""The record's fixtures: a fresh record on SQLite and on the PostgreSQL server, shared with the
station's tests (which keep the record the station writes)."""

from tests.station.conftest import record_url  # noqa: F401
