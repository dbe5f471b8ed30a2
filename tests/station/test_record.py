"""The record (:mod:`spacecal.ledger`) on SQLite and on a PostgreSQL server: robots, trackers,
calibrations, checks, imported JSONL histories, the versioned schema and ``--record``."""

from __future__ import annotations

import json

import pytest

from spacecal import app
from spacecal.cli.main import main
from tests.station.conftest import need


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """A simulated recording, its calibration (recorded nowhere yet) and one check in its
    JSONL history."""
    folder = tmp_path_factory.mktemp("calibrated")
    app.simulate(app.SimulateSettings(output=str(folder / "rec.csv")))
    app.calibrate(app.CalibrateSettings(str(folder / "rec.csv"), str(folder / "cal.json"), "ml"))
    app.check(app.CheckSettings(str(folder / "cal.json"), poses=2))
    return folder


def test_devices_calibrations_and_checks_are_kept(record_url, calibrated):
    need("sqlalchemy")
    from spacecal.io.results_json import read_calibration
    from spacecal.ledger import Ledger

    ledger = Ledger.open(record_url)
    try:
        robot = ledger.add_robot("UR10 <bay 1>", "sim", "UR10")
        assert ledger.add_robot("UR10 <bay 1>", "sim") == robot  # once per name
        tracker = ledger.add_tracker("Vicra", "sim", 20.0)
        calibration = read_calibration(calibrated / "cal.json")
        cal_id = ledger.record_calibration(calibration, calibrated / "cal.json", "station", robot, tracker)
        assert ledger.record_calibration(calibration, calibrated / "cal.json", "cli") == cal_id
        [row] = ledger.calibrations()
        assert row.content_sha256 == calibration.content_sha256
        assert row.robot == "UR10 <bay 1>" and row.tracker == "Vicra"
        assert row.grade == calibration.verdict.grade
        assert row.expected_error_mm == pytest.approx(calibration.verdict.expected_error_mm)
        # the JSONL history imports, once
        assert (
            ledger.import_history(calibrated / "cal.checks.jsonl", calibration, str(calibrated / "cal.json"))
            == 1
        )
        assert (
            ledger.import_history(calibrated / "cal.checks.jsonl", calibration, str(calibrated / "cal.json"))
            == 0
        )
        [check] = ledger.checks(cal_id)
        assert check.source == "import" and check.passed
        assert check.drift == pytest.approx(check.max_tcp_error_mm / row.expected_error_mm)
    finally:
        ledger.close()


def test_history_lines_of_other_calibrations_and_broken_lines_are_left_out(record_url, calibrated, tmp_path):
    need("sqlalchemy")
    from spacecal.io.results_json import read_calibration
    from spacecal.ledger import Ledger

    calibration = read_calibration(calibrated / "cal.json")
    lines = (calibrated / "cal.checks.jsonl").read_text().splitlines()
    other = json.loads(lines[0])
    other["calibration_sha256"] = "0" * 64
    history = tmp_path / "cal.checks.jsonl"
    history.write_text("\n".join([lines[0], json.dumps(other), "{not json", ""]))
    ledger = Ledger.open(record_url)
    try:
        assert ledger.import_history(history, calibration, str(calibrated / "cal.json")) == 1
    finally:
        ledger.close()


def test_the_schema_is_versioned_and_a_newer_record_is_refused(record_url):
    sa = need("sqlalchemy")
    from spacecal.core.errors import InvalidInputError
    from spacecal.ledger import Ledger, schema

    ledger = Ledger.open(record_url)
    with ledger.engine.begin() as connection:
        assert schema.stored_version(connection) == schema.CURRENT_VERSION
        connection.execute(
            sa.insert(schema.schema_version).values(version=schema.CURRENT_VERSION + 1, applied_utc="x")
        )
    ledger.close()
    with pytest.raises(InvalidInputError, match="newer than this spacecal"):
        Ledger.open(record_url)


def test_cli_calibrate_and_check_write_to_the_record(record_url, calibrated, tmp_path, capsys):
    need("sqlalchemy")
    from spacecal.ledger import Ledger

    cal = tmp_path / "cal.json"
    assert (
        main(
            [
                "calibrate",
                str(calibrated / "rec.csv"),
                "--method",
                "ml",
                "-o",
                str(cal),
                "--record",
                record_url,
            ]
        )
        == 0
    )
    assert main(["check", str(cal), "--poses", "2", "--record", record_url]) == 0
    ledger = Ledger.open(record_url)
    try:
        [row] = ledger.calibrations()
        assert row.source == "cli" and row.path == str(cal.resolve())
        [check] = ledger.checks(row.id)
        assert check.source == "cli"
    finally:
        ledger.close()


def test_a_record_that_cannot_be_opened_is_one_line(tmp_path, capsys):
    need("sqlalchemy")
    assert main(["check", str(tmp_path / "cal.json"), "--record", "nosuchdialect://x"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("spacecal: error: --record nosuchdialect://x") and err.count("\n") == 1
