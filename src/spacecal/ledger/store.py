"""Reading and writing the record (:mod:`spacecal.ledger.schema`): robots, trackers, tools,
calibrations and their checks."""

from __future__ import annotations

import datetime
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from spacecal.core.errors import InvalidInputError
from spacecal.ledger import schema
from spacecal.ledger.schema import sa
from spacecal.records import CalibrationResult, CheckResult

#: The names under which the record keeps the simulated robot and tracker.
SIMULATED_ROBOT, SIMULATED_TRACKER = "simulated robot", "simulated tracker"
#: The history line key that binds a JSONL check to the calibration it checked.
CALIBRATION_HASH_KEY = "calibration_sha256"


def _now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")


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

    Parameters
    ----------
    engine : sqlalchemy.Engine
        Use :meth:`open` to make one from a URL.
    """

    def __init__(self, engine: sa.Engine):
        self.engine = engine

    @classmethod
    def open(cls, url: str) -> Ledger:
        """Open (creating or migrating) the record at ``url`` (see :func:`ledger_url`)."""
        address = ledger_url(url)
        try:
            engine = sa.create_engine(address, future=True)
            schema.migrate(engine, _now())
        except sa.exc.ArgumentError as exc:
            raise InvalidInputError(f"--record {url}: not a database URL ({exc})") from exc
        except sa.exc.OperationalError as exc:
            raise InvalidInputError(
                f"--record {url}: cannot open the record ({' '.join(str(exc.orig).split())})"
            ) from exc
        return cls(engine)

    def close(self) -> None:
        self.engine.dispose()

    # -- devices ----------------------------------------------------------------------------

    def _named(self, table: sa.Table, name: str, values: dict[str, Any]) -> int:
        """The id of the row named ``name`` in ``table``, added with ``values`` if new."""
        with self.engine.begin() as connection:
            found = connection.execute(sa.select(table.c.id).where(table.c.name == name)).scalar()
            if found is not None:
                return int(found)
            inserted = connection.execute(
                sa.insert(table).values(name=name, created_utc=_now(), **values)
            ).inserted_primary_key
            assert inserted is not None
            return int(inserted[0])

    def add_robot(self, name: str, url: str, model: str | None = None) -> int:
        """The robot's id (added when new)."""
        _check_name(name, "robot")
        return self._named(schema.robots, name, {"url": url, "model": model})

    def add_tracker(self, name: str, url: str, rate_hz: float | None = None) -> int:
        """The tracker's id (added when new)."""
        _check_name(name, "tracker")
        return self._named(schema.trackers, name, {"url": url, "rate_hz": rate_hz})

    def add_tool(self, name: str, definition: str | None = None, tcp_in_flange: str | None = None) -> int:
        """The tool's id (added when new)."""
        _check_name(name, "tool")
        return self._named(schema.tools, name, {"definition": definition, "tcp_in_flange": tcp_in_flange})

    def robots(self) -> list[dict[str, Any]]:
        """Every robot, by name."""
        return self._rows(schema.robots)

    def trackers(self) -> list[dict[str, Any]]:
        """Every tracker, by name."""
        return self._rows(schema.trackers)

    def _rows(self, table: sa.Table) -> list[dict[str, Any]]:
        with self.engine.connect() as connection:
            return [dict(row._mapping) for row in connection.execute(sa.select(table).order_by(table.c.name))]

    def robot(self, robot_id: int) -> dict[str, Any] | None:
        return self._one(schema.robots, robot_id)

    def tracker(self, tracker_id: int) -> dict[str, Any] | None:
        return self._one(schema.trackers, tracker_id)

    def _one(self, table: sa.Table, row_id: int) -> dict[str, Any] | None:
        with self.engine.connect() as connection:
            row = connection.execute(sa.select(table).where(table.c.id == row_id)).first()
            return None if row is None else dict(row._mapping)

    # -- calibrations and checks ------------------------------------------------------------

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
        tracker given, the devices the calibration's provenance names are recorded by URL."""
        devices = calibration.provenance.devices if calibration.provenance is not None else {}
        if robot_id is None:
            robot_id = self._device_from_provenance(devices.get("robot"), "robot", calibration)
        if tracker_id is None:
            tracker_id = self._device_from_provenance(devices.get("tracker"), "tracker", calibration)
        verdict = calibration.verdict
        digest = calibration.content_sha256
        with self.engine.begin() as connection:
            found = connection.execute(
                sa.select(schema.calibrations.c.id).where(schema.calibrations.c.content_sha256 == digest)
            ).scalar()
            if found is not None:
                return int(found)
            inserted = connection.execute(
                sa.insert(schema.calibrations).values(
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
                )
            ).inserted_primary_key
            assert inserted is not None
            return int(inserted[0])

    def _device_from_provenance(self, device: Any, kind: str, calibration: CalibrationResult) -> int | None:
        simulated = calibration.provenance is not None and calibration.provenance.simulated
        url = device.get("url") if isinstance(device, dict) else None
        if not url and not simulated:
            return None
        url = str(url or "sim")
        name = {"robot": SIMULATED_ROBOT, "tracker": SIMULATED_TRACKER}[kind] if url == "sim" else url
        if kind == "robot":
            model = device.get("model") if isinstance(device, dict) else None
            return self.add_robot(name, url, None if model is None else str(model))
        return self.add_tracker(name, url)

    def calibration_id(self, content_sha256: str) -> int | None:
        with self.engine.connect() as connection:
            found = connection.execute(
                sa.select(schema.calibrations.c.id).where(
                    schema.calibrations.c.content_sha256 == content_sha256
                )
            ).scalar()
            return None if found is None else int(found)

    def record_check(self, calibration_id: int, check: CheckResult, source: str) -> int:
        """Record a check of the calibration ``calibration_id``; a check already recorded (the
        same record) is not added twice. Returns its id."""
        text = json.dumps(check.to_dict(), sort_keys=True, allow_nan=False)
        with self.engine.begin() as connection:
            found = connection.execute(
                sa.select(schema.checks.c.id).where(
                    schema.checks.c.calibration_id == calibration_id,
                    schema.checks.c.checked_utc == check.checked_utc,
                    schema.checks.c.record_json == text,
                )
            ).scalar()
            if found is not None:
                return int(found)
            inserted = connection.execute(
                sa.insert(schema.checks).values(
                    calibration_id=calibration_id,
                    checked_utc=check.checked_utc,
                    passed=bool(check.passed),
                    max_tcp_error_mm=float(max(check.tcp_error_mm)),
                    max_rotation_error_deg=float(max(check.rotation_error_deg)),
                    threshold_mm=float(check.threshold_mm),
                    simulated=check.simulated,
                    source=source,
                    record_json=text,
                )
            ).inserted_primary_key
            assert inserted is not None
            return int(inserted[0])

    def import_history(
        self, history: str | Path, calibration: CalibrationResult, calibration_path: str
    ) -> int:
        """Import a JSONL check history (``cal.checks.jsonl``) of ``calibration``: its lines
        bound to this calibration's content hash are recorded (once each); returns how many
        lines were new. Lines of another calibration or unreadable are left out, as
        ``spacecal report`` leaves them out."""
        calibration_id = self.record_calibration(calibration, calibration_path, source="import")
        before = len(self.checks(calibration_id))
        for line in Path(history).read_text(encoding="utf-8", errors="replace").splitlines():
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


def _check_name(name: str, what: str) -> None:
    if not isinstance(name, str) or not name.strip() or len(name) > 200:
        raise InvalidInputError(f"a {what} needs a name of 1..200 characters")
    if any(ord(ch) < 32 for ch in name):
        raise InvalidInputError(f"the {what}'s name must not contain control characters")


def finite_or_none(value: float | None) -> float | None:
    """``value`` when it is a finite number, else None (the record stores no NaN)."""
    return value if value is not None and math.isfinite(value) else None
