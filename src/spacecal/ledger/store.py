"""Reading and writing the record (:mod:`spacecal.ledger.schema`): robots, trackers, tools,
calibrations and their checks.

Every method that touches the database raises :class:`~spacecal.core.errors.RecordError`, in
one line, when the database cannot do it (locked past the busy timeout, damaged, unreachable,
full, read-only): whatever the caller was told was done is then known not to be recorded. A
record URL is only ever shown with its password replaced (:func:`redacted_url`).
"""

from __future__ import annotations

import datetime
import functools
import json
import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ParamSpec, TypeVar

from spacecal.core.errors import InvalidInputError, MissingExtraError, RecordError
from spacecal.core.text import (
    check_name,
    check_printable_token,
    exception_line,
    quoted,
    sanitize_for_terminal,
)
from spacecal.ledger import schema
from spacecal.ledger.schema import sa
from spacecal.models.robot_kinds import ROBOT_KINDS, is_robot_kind
from spacecal.records import CalibrationResult, CheckResult

#: The names under which the record keeps the simulated robot and tracker.
SIMULATED_ROBOT, SIMULATED_TRACKER = "simulated robot", "simulated tracker"
#: The history line key that binds a JSONL check to the calibration it checked.
CALIBRATION_HASH_KEY = "calibration_sha256"
#: How long a write waits for another writer's lock on an SQLite record before it fails, s:
#: the record's transactions last milliseconds, so a longer wait is a stuck writer.
BUSY_TIMEOUT_S = 5.0
#: How long a PostgreSQL record waits for a row or table lock, ms (the same bound).
LOCK_TIMEOUT_MS = 5000
#: How long connecting to a PostgreSQL server may take, s (an unreachable host otherwise waits
#: for the operating system's TCP timeout, minutes).
CONNECT_TIMEOUT_S = 10
#: The longest names, URLs, model names and texts of each column (the schema's lengths).
MAX_URL_CHARS, MAX_MODEL_CHARS, MAX_PATH_CHARS, MAX_TCP_TEXT_CHARS = 500, 100, 1000, 200
#: Tracker frame rates the record keeps, Hz: ``--tracker-rate-hz``'s range
#: (:data:`spacecal.app.devices.TRACKER_RATE_RANGE_HZ`, which the ledger's layer cannot import;
#: a test holds the two equal).
TRACKER_RATE_RANGE_HZ = (1.0, 1000.0)
#: Longest driver message kept in a :class:`RecordError`.
REASON_CHARS = 300
_URL_SCHEME = re.compile(r"[A-Za-z][A-Za-z0-9+.-]*://\S+", re.ASCII)

_P = ParamSpec("_P")
_R = TypeVar("_R")


def _now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")


def redacted_url(text: str) -> str:
    """A record URL (``--record``'s text or an SQLAlchemy URL) fit to print: its password as
    ``***`` (SQLAlchemy's ``URL.render_as_string(hide_password=True)``), terminal-safe and cut to
    200 characters. A text SQLAlchemy cannot parse loses everything between ``://`` and its last
    ``@`` instead, so no password survives a malformed URL either."""
    text = str(text)
    if "://" in text:
        try:
            address = sa.engine.make_url(text)
            if "@" in (address.host or ""):  # an '@' of the password not written %40
                raise ValueError("two '@'")
            text = address.render_as_string(hide_password=True)
        except (sa.exc.ArgumentError, ValueError):
            scheme, _, rest = text.partition("://")
            if "@" in rest:
                text = f"{scheme}://***@{rest.rpartition('@')[2]}"
    return sanitize_for_terminal(text)


def _password_of(address: sa.URL) -> str | None:
    return address.password if isinstance(address.password, str) and address.password else None


def _reason(exc: BaseException, password: str | None) -> str:
    """A database error's own message (the driver's, without SQLAlchemy's statement and link),
    on one line, without the password, terminal-safe and bounded."""
    orig = getattr(exc, "orig", None)
    text = exception_line(orig) if isinstance(orig, BaseException) else exception_line(exc)
    text = text.split("(Background on this error at:")[0].strip() or type(exc).__name__
    if password:
        text = text.replace(password, "***")
    return sanitize_for_terminal(text, REASON_CHARS)


def _database(doing: str) -> Callable[[Callable[_P, _R]], Callable[_P, _R]]:
    """Turn every SQLAlchemy error of a ledger method into one :class:`RecordError`: "the record
    could not be ``doing``: REASON"."""

    def wrap(method: Callable[_P, _R]) -> Callable[_P, _R]:
        @functools.wraps(method)
        def run(*args: _P.args, **kwargs: _P.kwargs) -> _R:
            try:
                return method(*args, **kwargs)
            except sa.exc.SQLAlchemyError as exc:
                ledger = args[0]
                password = ledger._password if isinstance(ledger, Ledger) else None
                raise RecordError(f"the record could not be {doing}: {_reason(exc, password)}") from exc

        return run

    return wrap


def ledger_url(text: str) -> str:
    """An SQLAlchemy URL from ``--record``: a URL (``sqlite:///...``, ``postgresql://...``)
    as given, a file path as an SQLite file (``postgresql://`` uses psycopg 3)."""
    if "://" in text:
        if text.startswith("postgresql://") or text.startswith("postgres://"):
            return "postgresql+psycopg://" + text.split("://", 1)[1]
        return text
    return "sqlite:///" + str(Path(text).expanduser().resolve())


@dataclass(frozen=True)
class CalibrationRow:
    """One calibration in the record."""

    id: int
    content_sha256: str
    path: str
    robot: str | None
    tracker: str | None
    method: str
    grade: str | None
    expected_error_mm: float | None
    created_utc: str
    source: str


@dataclass(frozen=True)
class CheckRow:
    """One check in the record, with the calibration it checked."""

    id: int
    calibration_id: int
    calibration_sha256: str
    robot: str | None
    checked_utc: str
    passed: bool
    max_tcp_error_mm: float
    max_rotation_error_deg: float
    threshold_mm: float
    expected_error_mm: float | None
    source: str

    @property
    def drift(self) -> float | None:
        """The check's largest TCP error over the calibration's expected error (None when the
        calibration has none)."""
        if not self.expected_error_mm:
            return None
        return self.max_tcp_error_mm / self.expected_error_mm


class Ledger:
    """The record, open on one database.

    Every method but :meth:`open` and :meth:`close` raises
    :class:`~spacecal.core.errors.RecordError` when the database fails it; the ``add_*``
    methods raise :class:`~spacecal.core.errors.InvalidInputError` for a value they refuse.

    Parameters
    ----------
    engine : sqlalchemy.Engine
        Use :meth:`open` to make one from a URL.
    """

    def __init__(self, engine: sa.Engine):
        self.engine = engine
        self._password = _password_of(engine.url)

    @property
    def shown_url(self) -> str:
        """The record's URL fit to print (password as ``***``; see :func:`redacted_url`)."""
        return redacted_url(self.engine.url.render_as_string(hide_password=True))

    @classmethod
    def open(cls, url: str) -> Ledger:
        """Open (creating or migrating) the record at ``url`` (see :func:`ledger_url`).

        An SQLite record is checked whole first (``PRAGMA quick_check``); its writes wait
        :data:`BUSY_TIMEOUT_S` for another writer's lock. Connecting to PostgreSQL may take
        :data:`CONNECT_TIMEOUT_S`, and its writes wait :data:`LOCK_TIMEOUT_MS` for a lock.

        Raises
        ------
        InvalidInputError
            ``url`` is not a database URL, or the record is of a newer spacecal.
        RecordError
            The database cannot be opened (unreachable, locked, not permitted) or an SQLite
            file is damaged (the message names the file).
        MissingExtraError
            The URL's database driver is not installed.
        """
        shown = redacted_url(url)
        try:
            address = sa.engine.make_url(ledger_url(url))
            engine = sa.create_engine(address, connect_args=_connect_args(address))
        except sa.exc.ArgumentError as exc:
            reason = _reason(exc, None)
            raise InvalidInputError(f"--record {shown}: not a database URL ({reason})") from None
        except ValueError:  # make_url's port that is not a number
            raise InvalidInputError(f"--record {shown}: not a database URL") from None
        except ImportError as exc:
            raise MissingExtraError(
                f"--record {shown}: the database driver is not installed ({exception_line(exc)}); "
                "pip install 'spacecal[station]'"
            ) from None
        if "@" in (address.host or ""):
            engine.dispose()
            raise InvalidInputError(f"--record {shown}: write an '@' of the user name or password as %40")
        password = _password_of(address)
        try:
            if engine.dialect.name == "sqlite":
                _refuse_damaged(engine, shown, password)
            schema.migrate(engine, _now())
        except sa.exc.SQLAlchemyError as exc:
            engine.dispose()
            raise RecordError(
                f"--record {shown}: cannot open the record ({_reason(exc, password)})"
            ) from None
        except BaseException:
            engine.dispose()
            raise
        return cls(engine)

    def close(self) -> None:
        self.engine.dispose()

    # -- devices ----------------------------------------------------------------------------

    def _insert_once(self, table: sa.Table, where: list[Any], values: dict[str, Any]) -> int:
        """The id of the row of ``table`` that ``where`` finds, inserted with ``values`` if none.

        Once also when another station inserts the same row at the same moment: the unique
        constraint refuses the second insert, which then finds the first one's row."""
        for attempt in range(2):
            try:
                with self.engine.begin() as connection:
                    found = connection.execute(sa.select(table.c.id).where(*where)).scalar()
                    if found is not None:
                        return int(found)
                    inserted = connection.execute(sa.insert(table).values(**values)).inserted_primary_key
                    assert inserted is not None
                    return int(inserted[0])
            except sa.exc.IntegrityError:
                if attempt:
                    raise
        raise AssertionError("unreachable")  # pragma: no cover

    def _named(self, table: sa.Table, name: str, values: dict[str, Any]) -> int:
        """The id of the row named ``name`` in ``table``, added with ``values`` if new."""
        return self._insert_once(
            table, [table.c.name == name], {"name": name, "created_utc": _now(), **values}
        )

    @_database("written")
    def add_robot(self, name: str, url: str, model: str | None = None) -> int:
        """The robot's id (added when new; a robot of that name already recorded keeps its URL
        and model).

        Parameters
        ----------
        name : str
            A name as :func:`spacecal.core.text.check_name` takes it (at most 200 characters).
        url : str
            ``sim`` or a device URL (at most :data:`MAX_URL_CHARS` printable characters, no
            space). The ledger checks only this form; the station checks that the URL is one a
            robot is opened with (:func:`spacecal.app.devices.validate_device_url`) first.
        model : str or None
            A registered robot kind (``UR10e``, ``FR3``, ...; :mod:`spacecal.models.robot_kinds`).

        Raises
        ------
        InvalidInputError
            A name, URL or model refused (one line).
        RecordError
            The database failed the write.
        """
        check_name(name, "robot name")
        _check_device_url(url, "robot")
        return self._named(schema.robots, name, {"url": url, "model": _check_model(model)})

    @_database("written")
    def add_tracker(self, name: str, url: str, rate_hz: float | None = None) -> int:
        """The tracker's id (added when new; a tracker of that name already recorded keeps its
        URL and rate).

        ``name`` and ``url`` as :meth:`add_robot` takes them; ``rate_hz`` None or a finite
        frame rate in :data:`TRACKER_RATE_RANGE_HZ` (``--tracker-rate-hz``'s range).

        Raises
        ------
        InvalidInputError
            A name, URL or rate refused (one line).
        RecordError
            The database failed the write.
        """
        check_name(name, "tracker name")
        _check_device_url(url, "tracker")
        return self._named(schema.trackers, name, {"url": url, "rate_hz": _check_rate(rate_hz)})

    @_database("written")
    def add_tool(self, name: str, definition: str | None = None, tcp_in_flange: str | None = None) -> int:
        """The tool's id (added when new): ``definition`` is the path of its NDI tool definition,
        ``tcp_in_flange`` the TCP as given (``X,Y,Z,RX,RY,RZ``), both printable, one line.

        Raises
        ------
        InvalidInputError
            A name or text refused (one line).
        RecordError
            The database failed the write.
        """
        check_name(name, "tool name")
        if definition is not None:
            check_name(definition, "the tool definition's path", MAX_PATH_CHARS)
        if tcp_in_flange is not None:
            check_printable_token(tcp_in_flange, "the tool's TCP", MAX_TCP_TEXT_CHARS)
        return self._named(schema.tools, name, {"definition": definition, "tcp_in_flange": tcp_in_flange})

    @_database("read")
    def robots(self) -> list[dict[str, Any]]:
        """Every robot, by name."""
        return self._rows(schema.robots)

    @_database("read")
    def trackers(self) -> list[dict[str, Any]]:
        """Every tracker, by name."""
        return self._rows(schema.trackers)

    def _rows(self, table: sa.Table) -> list[dict[str, Any]]:
        with self.engine.connect() as connection:
            return [dict(row._mapping) for row in connection.execute(sa.select(table).order_by(table.c.name))]

    @_database("read")
    def robot(self, robot_id: int) -> dict[str, Any] | None:
        return self._one(schema.robots, robot_id)

    @_database("read")
    def tracker(self, tracker_id: int) -> dict[str, Any] | None:
        return self._one(schema.trackers, tracker_id)

    def _one(self, table: sa.Table, row_id: int) -> dict[str, Any] | None:
        with self.engine.connect() as connection:
            row = connection.execute(sa.select(table).where(table.c.id == row_id)).first()
            return None if row is None else dict(row._mapping)

    # -- the station's workspaces -----------------------------------------------------------

    @_database("written")
    def add_workspace(
        self, robot_id: int, tracker_id: int, folder: str, rom: str | None = None, tool_id: int | None = None
    ) -> int:
        """A new workspace's id: a calibration in progress at the station, in ``folder``.

        Ids are never reused, so a link to a workspace names it across restarts.

        Raises
        ------
        InvalidInputError
            An unknown robot or tracker, or a folder already recorded (one line).
        RecordError
            The database failed the write.
        """
        if self._one(schema.robots, robot_id) is None or self._one(schema.trackers, tracker_id) is None:
            raise InvalidInputError("a workspace needs a robot and a tracker of the record")
        with self.engine.begin() as connection:
            taken = connection.execute(
                sa.select(schema.workspaces.c.id).where(schema.workspaces.c.folder == folder)
            ).first()
            if taken is not None:
                raise InvalidInputError(f"the folder {folder[:200]} is workspace {taken[0]}'s already")
            result = connection.execute(
                sa.insert(schema.workspaces).values(
                    robot_id=robot_id,
                    tracker_id=tracker_id,
                    tool_id=tool_id,
                    folder=folder,
                    rom=rom,
                    created_utc=_now(),
                )
            )
            key = result.inserted_primary_key
            assert key is not None  # an insert of one row
            return int(key[0])

    @_database("read")
    def workspaces(self) -> list[dict[str, Any]]:
        """Every workspace recorded, oldest first."""
        with self.engine.connect() as connection:
            table = schema.workspaces
            return [dict(row._mapping) for row in connection.execute(sa.select(table).order_by(table.c.id))]

    # -- calibrations and checks ------------------------------------------------------------

    @_database("written")
    def record_calibration(
        self,
        calibration: CalibrationResult,
        path: str | Path,
        source: str,
        robot_id: int | None = None,
        tracker_id: int | None = None,
        tool_id: int | None = None,
    ) -> int:
        """Record a calibration (once per content hash) and return its id. Without a robot or
        tracker given, the devices the calibration's provenance names are recorded by URL (a
        device whose URL or model the record refuses is left unnamed; the calibration file
        keeps what its provenance says).

        Raises
        ------
        RecordError
            The database failed the write: the calibration is not recorded.
        """
        devices = calibration.provenance.devices if calibration.provenance is not None else {}
        if robot_id is None:
            robot_id = self._device_from_provenance(devices.get("robot"), "robot", calibration)
        if tracker_id is None:
            tracker_id = self._device_from_provenance(devices.get("tracker"), "tracker", calibration)
        verdict = calibration.verdict
        digest = calibration.content_sha256
        return self._insert_once(
            schema.calibrations,
            [schema.calibrations.c.content_sha256 == digest],
            dict(
                content_sha256=digest,
                path=str(Path(path).resolve()),
                robot_id=robot_id,
                tracker_id=tracker_id,
                tool_id=tool_id,
                method=calibration.method,
                grade=None if verdict is None else verdict.grade,
                expected_error_mm=None if verdict is None else verdict.expected_error_mm,
                simulated=None if calibration.provenance is None else calibration.provenance.simulated,
                created_utc=(
                    calibration.provenance.created_utc if calibration.provenance is not None else _now()
                ),
                recorded_utc=_now(),
                source=source,
            ),
        )

    def _device_from_provenance(self, device: Any, kind: str, calibration: CalibrationResult) -> int | None:
        simulated = calibration.provenance is not None and calibration.provenance.simulated
        url = device.get("url") if isinstance(device, dict) else None
        if not url and not simulated:
            return None
        url = str(url or "sim")
        name = {"robot": SIMULATED_ROBOT, "tracker": SIMULATED_TRACKER}[kind] if url == "sim" else url
        try:
            if kind == "robot":
                model = device.get("model") if isinstance(device, dict) else None
                known = model if is_robot_kind(model) else None
                return self.add_robot(name, url, known)
            return self.add_tracker(name, url)
        except InvalidInputError:  # a calibration file's provenance is not the record's to trust
            return None

    @_database("read")
    def calibration_id(self, content_sha256: str) -> int | None:
        with self.engine.connect() as connection:
            found = connection.execute(
                sa.select(schema.calibrations.c.id).where(
                    schema.calibrations.c.content_sha256 == content_sha256
                )
            ).scalar()
            return None if found is None else int(found)

    @_database("written")
    def record_check(self, calibration_id: int, check: CheckResult, source: str) -> int:
        """Record a check of the calibration ``calibration_id``; a check already recorded (the
        same record) is not added twice. Returns its id.

        Raises
        ------
        RecordError
            The database failed the write: the check is not recorded.
        """
        text = json.dumps(check.to_dict(), sort_keys=True, allow_nan=False)
        k = schema.checks
        return self._insert_once(
            k,
            [
                k.c.calibration_id == calibration_id,
                k.c.checked_utc == check.checked_utc,
                k.c.record_json == text,
            ],
            dict(
                calibration_id=calibration_id,
                checked_utc=check.checked_utc,
                passed=bool(check.passed),
                max_tcp_error_mm=float(max(check.tcp_error_mm)),
                max_rotation_error_deg=float(max(check.rotation_error_deg)),
                threshold_mm=float(check.threshold_mm),
                simulated=check.simulated,
                source=source,
                record_json=text,
            ),
        )

    @_database("written")
    def import_history(
        self, history: str | Path, calibration: CalibrationResult, calibration_path: str
    ) -> int:
        """Import a JSONL check history (``cal.checks.jsonl``) of ``calibration``: its lines
        bound to this calibration's content hash are recorded (once each); returns how many
        lines were new. Lines of another calibration or unreadable are left out, as
        ``spacecal report`` leaves them out.

        Raises
        ------
        InvalidInputError
            The history file cannot be read.
        RecordError
            The database failed a write: the lines from that one on are not recorded.
        """
        try:
            lines = Path(history).read_text(encoding="utf-8", errors="replace").splitlines()
        except OSError as exc:
            raise InvalidInputError(
                f"cannot read the check history {quoted(str(history))}: {exception_line(exc)}"
            ) from None
        calibration_id = self.record_calibration(calibration, calibration_path, source="import")
        before = len(self.checks(calibration_id))
        for line in lines:
            if not line.strip():
                continue
            try:
                data = json.loads(line)
                if not isinstance(data, dict) or data.get(CALIBRATION_HASH_KEY) != calibration.content_sha256:
                    continue
                check = CheckResult.from_dict(data, what=str(history))
            except (ValueError, RecursionError):
                continue
            self.record_check(calibration_id, check, source="import")
        return len(self.checks(calibration_id)) - before

    @_database("read")
    def calibrations(self) -> list[CalibrationRow]:
        """Every calibration, oldest first."""
        c, r, t = schema.calibrations, schema.robots, schema.trackers
        query = (
            sa.select(c, r.c.name.label("robot_name"), t.c.name.label("tracker_name"))
            .select_from(c.outerjoin(r, c.c.robot_id == r.c.id).outerjoin(t, c.c.tracker_id == t.c.id))
            .order_by(c.c.created_utc, c.c.id)
        )
        with self.engine.connect() as connection:
            return [
                CalibrationRow(
                    row.id,
                    row.content_sha256,
                    row.path,
                    row.robot_name,
                    row.tracker_name,
                    row.method,
                    row.grade,
                    row.expected_error_mm,
                    row.created_utc,
                    row.source,
                )
                for row in connection.execute(query)
            ]

    @_database("read")
    def checks(self, calibration_id: int | None = None) -> list[CheckRow]:
        """Every check (of one calibration when given), oldest first."""
        k, c, r = schema.checks, schema.calibrations, schema.robots
        query = (
            sa.select(
                k,
                c.c.content_sha256,
                c.c.expected_error_mm,
                r.c.name.label("robot_name"),
            )
            .select_from(k.join(c, k.c.calibration_id == c.c.id).outerjoin(r, c.c.robot_id == r.c.id))
            .order_by(k.c.checked_utc, k.c.id)
        )
        if calibration_id is not None:
            query = query.where(k.c.calibration_id == calibration_id)
        with self.engine.connect() as connection:
            return [
                CheckRow(
                    row.id,
                    row.calibration_id,
                    row.content_sha256,
                    row.robot_name,
                    row.checked_utc,
                    bool(row.passed),
                    row.max_tcp_error_mm,
                    row.max_rotation_error_deg,
                    row.threshold_mm,
                    row.expected_error_mm,
                    row.source,
                )
                for row in connection.execute(query)
            ]


def _connect_args(address: sa.URL) -> dict[str, Any]:
    """The driver's deadlines: SQLite's busy timeout; libpq's connect and lock timeouts."""
    if address.get_backend_name() == "sqlite":
        return {"timeout": BUSY_TIMEOUT_S}
    if address.get_backend_name() == "postgresql" and address.get_driver_name() in ("psycopg", "psycopg2"):
        return {"connect_timeout": CONNECT_TIMEOUT_S, "options": f"-c lock_timeout={LOCK_TIMEOUT_MS}"}
    return {}


def _refuse_damaged(engine: sa.Engine, shown: str, password: str | None) -> None:
    """Refuse an SQLite record whose file is not a database or fails ``PRAGMA quick_check``
    (SQLite's own page, index and constraint check, without comparing index contents), naming
    the file: writing to a damaged record could lose what it still holds."""
    try:
        with engine.connect() as connection:
            findings = [str(row[0]) for row in connection.exec_driver_sql("PRAGMA quick_check")]
    except sa.exc.OperationalError:
        raise  # locked, not permitted, no such folder: not damage
    except sa.exc.DatabaseError as exc:  # SQLITE_NOTADB, SQLITE_CORRUPT
        findings = [_reason(exc, password)]
    if findings != ["ok"]:
        first = sanitize_for_terminal(" ".join(findings[0].split()), REASON_CHARS)
        more = f" (and {len(findings) - 1} more findings)" if len(findings) > 1 else ""
        raise RecordError(
            f"--record {shown}: the record file {sanitize_for_terminal(engine.url.database)} is damaged: "
            f"{first}{more}; restore it from a backup or move it aside (a new record is made where none is)"
        )


def _check_device_url(url: object, kind: str) -> str:
    """``url`` if it is ``sim`` or looks like a device URL (``scheme://...``), printable, one
    line, at most :data:`MAX_URL_CHARS` characters."""
    text = check_printable_token(url, f"the {kind}'s URL", MAX_URL_CHARS)
    if text != "sim" and not _URL_SCHEME.fullmatch(text):
        raise InvalidInputError(f"the {kind}'s URL {quoted(text)} is not a device URL (scheme://...) or sim")
    return text


def _check_model(model: object) -> str | None:
    """``model`` if it is None or a registered robot kind (:mod:`spacecal.models.robot_kinds`)."""
    if model is None:
        return None
    text = check_printable_token(model, "the robot's model", MAX_MODEL_CHARS)
    if not is_robot_kind(text):
        known = ", ".join(ROBOT_KINDS)
        raise InvalidInputError(f"unknown robot model {quoted(text)}; known: {known}")
    return text


def _check_rate(rate_hz: object) -> float | None:
    """``rate_hz`` if it is None or a finite frame rate in :data:`TRACKER_RATE_RANGE_HZ`."""
    if rate_hz is None:
        return None
    low, high = TRACKER_RATE_RANGE_HZ
    if isinstance(rate_hz, bool) or not isinstance(rate_hz, (int, float)):
        raise InvalidInputError(f"the tracker's frame rate must be a number in {low:g}..{high:g} Hz")
    if not (math.isfinite(rate_hz) and low <= rate_hz <= high):
        raise InvalidInputError(
            f"the tracker's frame rate must be a number in {low:g}..{high:g} Hz, got {rate_hz}"
        )
    return float(rate_hz)


def finite_or_none(value: float | None) -> float | None:
    """``value`` when it is a finite number, else None (the record stores no NaN)."""
    return value if value is not None and math.isfinite(value) else None
