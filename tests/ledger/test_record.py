"""The record (:mod:`spacecal.ledger`) on SQLite and on a PostgreSQL server: robots, trackers,
calibrations, checks, imported JSONL histories, the versioned schema and ``--record``."""

from __future__ import annotations

import contextlib
import json
import sqlite3
from collections.abc import Iterator

import pytest

from spacecal import app
from spacecal.cli.main import main
from tests.station.conftest import need


@contextlib.contextmanager
def another_writer(record) -> Iterator[None]:
    """The SQLite record held by another writer (BEGIN IMMEDIATE) for the ``with`` block."""
    other = sqlite3.connect(record, isolation_level=None)
    try:
        other.execute("BEGIN IMMEDIATE")
        yield
    finally:
        other.execute("ROLLBACK")
        other.close()


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


# -- what the record refuses --------------------------------------------------------------

#: Characters no name holds: C0 controls and newlines, DEL, C1 controls, bidirectional
#: overrides, isolates and marks, line and paragraph separators, zero-width characters.
REFUSED_CHARACTERS = [
    *map(chr, range(0x00, 0x20)),
    "\x7f",
    *map(chr, range(0x80, 0xA0)),
    *map(chr, range(0x202A, 0x202F)),
    *map(chr, range(0x2066, 0x206A)),
    "\u200e",
    "\u200f",
    "\u061c",
    "\u2028",
    "\u2029",
    "\u200b",
    "\ufeff",
    "\u00a0",
]


def _one_line(error: BaseException) -> str:
    from spacecal.core.text import sanitize_for_terminal

    message = str(error)
    assert message and "\n" not in message and len(message) < 400, message[:400]
    assert message == sanitize_for_terminal(message, 10**6), message  # nothing a terminal acts on
    return message


def test_names_that_do_not_print_as_themselves_are_refused(record_url):
    need("sqlalchemy")
    from spacecal.core.errors import InvalidInputError
    from spacecal.ledger import Ledger

    ledger = Ledger.open(record_url)
    try:
        adders = {
            "robot": lambda name: ledger.add_robot(name, "sim"),
            "tracker": lambda name: ledger.add_tracker(name, "sim"),
            "tool": lambda name: ledger.add_tool(name),
        }
        for kind, add in adders.items():
            names = [f"bay{c}1" for c in REFUSED_CHARACTERS] + [
                "",
                " ",
                " bay",
                "bay ",
                "x" * 201,
                "x\n" * 5000,
            ]
            for name in names:
                with pytest.raises(InvalidInputError) as refused:
                    add(name)
                assert _one_line(refused.value).startswith(f"{kind} name")
            for name in ("UR10 <bay 1>", "é中 bay", "a" * 200, "x&y", "$x$"):
                assert add(name) == add(name)
        assert sorted(r["name"] for r in ledger.robots()) == sorted(
            ["UR10 <bay 1>", "é中 bay", "a" * 200, "x&y", "$x$"]
        )
    finally:
        ledger.close()


def test_device_urls_models_and_rates_are_checked(record_url):
    need("sqlalchemy")
    from spacecal.core.errors import InvalidInputError
    from spacecal.ledger import Ledger

    ledger = Ledger.open(record_url)
    try:
        bad_robots = [
            ("ur://" + "h" * 10_000, None),
            ("ur://host\nevil", None),
            ("ur://host evil", None),
            ("host", None),
            ("", None),
            ("ur://host", "UR10\nx"),
            ("ur://host", "U" * 10_000),
            ("ur://host", "ur10"),
            ("ur://host", "UR20"),
        ]
        for url, model in bad_robots:
            with pytest.raises(InvalidInputError) as refused:
                ledger.add_robot("r", url, model)
            _one_line(refused.value)
        for rate in (float("nan"), float("inf"), 0.0, -20.0, 0.5, 1000.5, 1e9, True, "20"):
            with pytest.raises(InvalidInputError) as refused:
                ledger.add_tracker("t", "igtl://host:18944", rate)
            _one_line(refused.value)
        with pytest.raises(InvalidInputError):
            ledger.add_tool("tool", definition="marker.rom\nx")
        assert ledger.robots() == [] and ledger.trackers() == []
        ledger.add_robot("r", "ur://10.0.0.2", "UR10e")
        ledger.add_tracker("t", "ndi:///dev/ttyUSB0", 60)
        ledger.add_tracker("t2", "igtl://host:18944", 1000)
        assert [(r["url"], r["model"]) for r in ledger.robots()] == [("ur://10.0.0.2", "UR10e")]
        assert [t["rate_hz"] for t in ledger.trackers()] == [60.0, 1000.0]
    finally:
        ledger.close()


def test_the_record_and_the_command_line_take_the_same_tracker_rates(tmp_path):
    need("sqlalchemy")
    from spacecal.app.devices import TRACKER_RATE_RANGE_HZ, check_tracker_rate_hz
    from spacecal.core.errors import InvalidInputError
    from spacecal.ledger import Ledger, store

    assert store.TRACKER_RATE_RANGE_HZ == TRACKER_RATE_RANGE_HZ
    ledger = Ledger.open(f"sqlite:///{tmp_path / 'r.db'}")
    try:
        for k, rate in enumerate([0.0, 0.999, 1.0, 20.0, 999.9, 1000.0, 1000.01, float("nan"), -1.0]):
            try:
                check_tracker_rate_hz(rate)
                cli = True
            except InvalidInputError:
                cli = False
            try:
                ledger.add_tracker(f"t{k}", "sim", rate)
                record = True
            except InvalidInputError:
                record = False
            assert cli == record, rate
    finally:
        ledger.close()


def test_validate_device_url_takes_what_the_command_line_opens():
    from spacecal.adapters import device_address
    from spacecal.app.devices import validate_device_url
    from spacecal.core.errors import InvalidInputError

    good = {
        "robot": ["sim", "ur://10.0.0.2", "ur://robot.local"],
        "tracker": ["sim", "ndi:///dev/ttyUSB0", "ndi://vega.local", "ndi://10.0.0.3:8765", "igtl://h:18944"],
    }
    for kind, urls in good.items():
        for url in urls:
            assert validate_device_url(kind, url) == url
            if url != "sim":
                device_address(url, kind)  # the parser that opens the device takes it too
    bad = {
        "robot": [
            "igtl://h:18944",
            "ur://",
            "ur://h:99999",
            "ur://h\n",
            "ur://h\tx",
            "ur://" + "h" * 600,
            "x",
        ],
        "tracker": ["ur://h", "igtl://h:port", "ndi://h\u202e", "", " sim", 20],
    }
    for kind, urls in bad.items():
        for url in urls:
            with pytest.raises(InvalidInputError) as refused:
                validate_device_url(kind, url)
            _one_line(refused.value)
    with pytest.raises(InvalidInputError):
        validate_device_url("tool", "sim")


# -- a record that fails ------------------------------------------------------------------


def _calibration(calibrated):
    from spacecal.io.results_json import read_calibration

    return read_calibration(calibrated / "cal.json")


def test_a_locked_sqlite_record_raises_record_error_and_keeps_nothing(tmp_path, calibrated, monkeypatch):
    need("sqlalchemy")
    import sqlite3

    from spacecal.core.errors import RecordError
    from spacecal.ledger import Ledger, store

    path = tmp_path / "record.db"
    ledger = Ledger.open(str(path))
    with ledger.engine.connect() as connection:  # the busy timeout is set, in ms
        assert connection.exec_driver_sql("PRAGMA busy_timeout").scalar() == store.BUSY_TIMEOUT_S * 1000
    ledger.close()
    monkeypatch.setattr(store, "BUSY_TIMEOUT_S", 0.2)
    ledger = Ledger.open(str(path))
    robot = ledger.add_robot("UR10", "sim")
    other = sqlite3.connect(path, isolation_level=None)
    try:
        other.execute("BEGIN EXCLUSIVE")  # another writer that holds the record
        writes = [
            lambda: ledger.add_robot("UR10e", "sim"),
            lambda: ledger.add_tracker("Vega", "sim"),
            lambda: ledger.add_tool("marker"),
            lambda: ledger.record_calibration(
                _calibration(calibrated), calibrated / "cal.json", "cli", robot
            ),
            lambda: ledger.import_history(
                calibrated / "cal.checks.jsonl", _calibration(calibrated), str(calibrated / "cal.json")
            ),
        ]
        reads = [
            ledger.robots,
            ledger.trackers,
            ledger.calibrations,
            ledger.checks,
            lambda: ledger.robot(robot),
        ]
        for doing, calls in (("written", writes), ("read", reads)):
            for call in calls:
                with pytest.raises(RecordError) as failed:
                    call()
                assert _one_line(failed.value) == f"the record could not be {doing}: database is locked"
                assert isinstance(failed.value, OSError)
        with pytest.raises(RecordError, match="cannot open the record \\(database is locked\\)"):
            Ledger.open(str(path))
    finally:
        other.execute("ROLLBACK")
        other.close()
    assert [r["name"] for r in ledger.robots()] == ["UR10"]
    assert ledger.trackers() == [] and ledger.calibrations() == []
    ledger.close()


def test_a_locked_postgresql_record_raises_record_error(record_url, monkeypatch):
    sa = need("sqlalchemy")
    if not record_url.startswith("postgresql"):
        pytest.skip("PostgreSQL's lock timeout")
    from spacecal.core.errors import RecordError
    from spacecal.ledger import Ledger, ledger_url, store

    monkeypatch.setattr(store, "LOCK_TIMEOUT_MS", 200)
    ledger = Ledger.open(record_url)
    other = sa.create_engine(ledger_url(record_url))
    try:
        with other.begin() as connection:
            connection.execute(sa.text("LOCK TABLE robots IN ACCESS EXCLUSIVE MODE"))
            with pytest.raises(RecordError) as failed:
                ledger.add_robot("UR10", "sim")
            assert _one_line(failed.value).startswith("the record could not be written: ")
            assert "lock timeout" in str(failed.value)
        assert ledger.robots() == []
    finally:
        other.dispose()
        ledger.close()


def test_a_damaged_sqlite_record_is_refused_at_open_naming_the_file(tmp_path):
    need("sqlalchemy")
    from spacecal.core.errors import RecordError
    from spacecal.ledger import Ledger

    not_a_database = tmp_path / "notes.db"
    not_a_database.write_bytes(b"these are not the records you are looking for\n" * 100)
    with pytest.raises(RecordError) as refused:
        Ledger.open(str(not_a_database))
    assert f"the record file {not_a_database} is damaged: file is not a database" in _one_line(refused.value)

    damaged = tmp_path / "record.db"
    ledger = Ledger.open(str(damaged))
    for k in range(300):
        ledger.add_robot(f"robot {k}", f"ur://host{k}")
    page_size = ledger.engine.connect().exec_driver_sql("PRAGMA page_size").scalar()
    ledger.close()
    content = bytearray(damaged.read_bytes())
    content[3 * page_size : 3 * page_size + 512] = b"\xab" * 512  # one b-tree page overwritten
    damaged.write_bytes(bytes(content))
    with pytest.raises(RecordError) as refused:
        Ledger.open(str(damaged))
    assert f"the record file {damaged} is damaged: " in _one_line(refused.value)


def test_two_stations_adding_the_same_device_at_once_get_one_row(record_url):
    need("sqlalchemy")
    import threading

    from spacecal.ledger import Ledger

    first, second = Ledger.open(record_url), Ledger.open(record_url)
    ids: list[int] = []
    errors: list[BaseException] = []

    def add(ledger, k):
        try:
            ids.append(ledger.add_robot(f"UR10 bay {k % 2}", "sim"))
        except BaseException as exc:
            errors.append(exc)

    try:
        threads = [threading.Thread(target=add, args=((first, second)[k % 2], k // 2)) for k in range(16)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join(timeout=60)
        assert errors == [] and len(ids) == 16
        assert len(set(ids)) == 2 and len(first.robots()) == 2
    finally:
        first.close()
        second.close()


def test_a_calibration_not_recorded_is_said_so_in_one_line(tmp_path, calibrated, monkeypatch, capsys):
    need("sqlalchemy")

    from spacecal.ledger import Ledger, store

    monkeypatch.setattr(store, "BUSY_TIMEOUT_S", 0.2)
    record = tmp_path / "record.db"
    Ledger.open(str(record)).close()
    cal = tmp_path / "cal.json"
    # another writer: reading (opening the record) still works, writing waits and fails
    with another_writer(record):
        code = main(
            [
                "calibrate",
                str(calibrated / "rec.csv"),
                "--method",
                "ml",
                "-o",
                str(cal),
                "--record",
                str(record),
            ]
        )
    err = capsys.readouterr().err
    assert code == 1 and err.count("\n") == 1, err
    assert err == (
        "spacecal: error: cal.json was written but not recorded: the record could not be written: "
        "database is locked\n"
    )
    assert cal.exists()
    with another_writer(record):
        code = main(["check", str(cal), "--poses", "2", "--record", str(record)])
    err = capsys.readouterr().err
    assert code == 1 and err.count("\n") == 1, err
    assert err == (
        "spacecal: error: the check was written to its history cal.checks.jsonl but not recorded: the record "
        "could not be written: database is locked\n"
    )
    assert (tmp_path / "cal.checks.jsonl").read_text().count("\n") == 1
    ledger = Ledger.open(str(record))
    assert ledger.calibrations() == [] and ledger.checks() == []
    ledger.close()


def test_a_record_url_is_never_shown_with_its_password(tmp_path, calibrated, capsys):
    need("sqlalchemy")
    need("psycopg")
    from spacecal.ledger import Ledger, redacted_url
    from tests.station.conftest import free_port

    url = f"postgresql://user:secretpw@127.0.0.1:{free_port()}/db"  # nothing listens there
    for record in (url, "postgresql://user:secretpw@127.0.0.1:port/db", "postgresql://user:secret@pw@h/db"):
        code = main(
            ["calibrate", str(calibrated / "rec.csv"), "-o", str(tmp_path / "cal.json"), "--record", record]
        )
        err = capsys.readouterr().err
        assert code == 1 and err.count("\n") == 1 and err.startswith("spacecal: error: --record "), err
        assert "secret" not in err and "pw@" not in err, err
    assert not (tmp_path / "cal.json").exists()  # the record is opened before anything is written
    assert redacted_url(url) == url.replace("secretpw", "***")
    assert redacted_url("sqlite:////x/record.db") == "sqlite:////x/record.db"
    assert redacted_url("/x/record.db") == "/x/record.db"
    ledger = Ledger.open(f"sqlite:///{tmp_path / 'r.db'}")
    assert ledger.shown_url == f"sqlite:///{tmp_path / 'r.db'}"
    ledger.close()
