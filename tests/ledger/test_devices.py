"""The record's robots and trackers as the station keeps them (:mod:`spacecal.ledger.devices`),
on SQLite and on a PostgreSQL server: a new one under a name of its own, edited, retired and
back in service, deleted only while no calibration names it; and a version-2 record brought to
version 3 with its devices kept."""

from __future__ import annotations

import pytest

from tests.station.conftest import need


@pytest.fixture
def ledger(record_url):
    need("sqlalchemy")
    from spacecal.ledger import Ledger

    opened = Ledger.open(record_url)
    try:
        yield opened
    finally:
        opened.close()


def test_a_taken_name_is_refused_retired_or_not(ledger):
    from spacecal.ledger import NameTakenError

    first = ledger.new_device("robot", "UR10 bay 1", "ur://10.0.0.2", model="UR10")
    with pytest.raises(NameTakenError, match="already"):
        ledger.new_device("robot", "UR10 bay 1", "sim")
    ledger.retire_device("robot", first)
    with pytest.raises(NameTakenError, match="retired"):
        ledger.new_device("robot", "UR10 bay 1", "sim")
    # a tracker may share a robot's name: the kinds are apart
    ledger.new_device("tracker", "UR10 bay 1", "sim", rate_hz=60.0)
    assert [(r["name"], r["url"], r["model"]) for r in ledger.robots()] == [
        ("UR10 bay 1", "ur://10.0.0.2", "UR10")
    ]
    # add_robot keeps finding a device by its name (the command line's provenance)
    assert ledger.add_robot("UR10 bay 1", "sim") == first


def test_an_edit_is_checked_as_a_new_device_and_keeps_the_id(ledger):
    from spacecal.core.errors import InvalidInputError
    from spacecal.ledger import NameTakenError

    vicra = ledger.new_device("tracker", "Vicra", "sim")
    ledger.new_device("tracker", "Vega", "sim")
    ledger.edit_device("tracker", vicra, "Vicra OR-2", "ndi://10.0.0.9", rate_hz=20.0)
    row = ledger.tracker(vicra)
    assert (row["name"], row["url"], row["rate_hz"]) == ("Vicra OR-2", "ndi://10.0.0.9", 20.0)
    with pytest.raises(NameTakenError):
        ledger.edit_device("tracker", vicra, "Vega", "sim")
    for rate in (-20.0, 0.0, 1e9, float("nan")):
        with pytest.raises(InvalidInputError, match="frame rate must be"):
            ledger.edit_device("tracker", vicra, "Vicra OR-2", "sim", rate_hz=rate)
    with pytest.raises(InvalidInputError, match="no tracker 99"):
        ledger.edit_device("tracker", 99, "x", "sim")
    assert ledger.tracker(vicra)["url"] == "ndi://10.0.0.9"  # nothing refused was written


def test_a_device_a_calibration_names_is_kept_and_an_unused_one_deleted(ledger, tmp_path):
    from spacecal.ledger import DeviceInUseError

    robot = ledger.new_device("robot", "UR10 bay 1", "sim")
    tracker = ledger.new_device("tracker", "Vicra", "sim")
    spare = ledger.new_device("robot", "spare", "sim")
    ledger.add_workspace(robot, tracker, str(tmp_path / "w1"))  # a calibration in progress
    assert ledger.device_uses("robot", robot) == 1 and ledger.device_uses("robot", spare) == 0
    with pytest.raises(DeviceInUseError, match="retire it instead"):
        ledger.delete_device("robot", robot)
    with pytest.raises(DeviceInUseError):
        ledger.delete_device("tracker", tracker)
    ledger.delete_device("robot", spare)
    assert [r["id"] for r in ledger.robots()] == [robot]
    ledger.retire_device("robot", robot)
    assert ledger.robot(robot)["retired_utc"] is not None and ledger.workspaces()[0]["robot_id"] == robot
    ledger.retire_device("robot", robot, retired=False)
    assert ledger.robot(robot)["retired_utc"] is None


def test_a_version_2_record_is_brought_to_version_3_keeping_its_devices(record_url):
    sa = need("sqlalchemy")
    from spacecal.ledger import Ledger, schema

    ledger = Ledger.open(record_url)
    ledger.add_robot("UR10 bay 1", "ur://10.0.0.2", "UR10")
    with ledger.engine.begin() as connection:  # as spacecal of schema version 2 left it
        for table in ("robots", "trackers"):
            connection.execute(sa.text(f"ALTER TABLE {table} DROP COLUMN retired_utc"))
        connection.execute(sa.delete(schema.schema_version).where(schema.schema_version.c.version == 3))
    ledger.close()
    ledger = Ledger.open(record_url)
    try:
        with ledger.engine.connect() as connection:
            assert schema.stored_version(connection) == 3 == schema.CURRENT_VERSION
        [robot] = ledger.robots()
        assert (robot["name"], robot["url"], robot["model"], robot["retired_utc"]) == (
            "UR10 bay 1",
            "ur://10.0.0.2",
            "UR10",
            None,
        )
        ledger.retire_device("robot", robot["id"])
        assert ledger.robots()[0]["retired_utc"] is not None
    finally:
        ledger.close()
