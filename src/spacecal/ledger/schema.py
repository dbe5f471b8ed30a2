"""The record's tables and their versioned migrations.

Why a small versioned schema table and not Alembic: the record has five tables that only ever
grow; each migration is one function of this module, applied in order inside one transaction
and recorded in ``schema_version``, so a wheel ships every migration with the code that needs
it and a station opening an older record (SQLite or PostgreSQL) brings it up to date before
anything else touches it. Alembic's script directory, ``env.py`` and ini file would add a
second place to keep in step for no gain at this size; should the record ever need branching
migrations, its revisions can start from the version kept here.
"""

from __future__ import annotations

from collections.abc import Callable

from spacecal.core.errors import InvalidInputError

try:
    import sqlalchemy as sa
except ImportError as exc:  # pragma: no cover - exercised by the missing-extra test
    from spacecal.core.errors import MissingExtraError

    raise MissingExtraError(
        "the calibration record needs the station extra: pip install 'spacecal[station]'"
    ) from exc

metadata = sa.MetaData()

schema_version = sa.Table(
    "schema_version",
    metadata,
    sa.Column("version", sa.Integer, primary_key=True),
    sa.Column("applied_utc", sa.String(40), nullable=False),
)

robots = sa.Table(
    "robots",
    metadata,
    sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
    sa.Column("name", sa.String(200), nullable=False, unique=True),
    sa.Column("url", sa.String(500), nullable=False),
    sa.Column("model", sa.String(100)),
    sa.Column("created_utc", sa.String(40), nullable=False),
    # when the robot was retired (version 3): kept for the calibrations that name it, offered
    # for no new one; None while in service
    sa.Column("retired_utc", sa.String(40)),
)

trackers = sa.Table(
    "trackers",
    metadata,
    sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
    sa.Column("name", sa.String(200), nullable=False, unique=True),
    sa.Column("url", sa.String(500), nullable=False),
    sa.Column("rate_hz", sa.Float),
    sa.Column("created_utc", sa.String(40), nullable=False),
    sa.Column("retired_utc", sa.String(40)),  # as the robots' (version 3)
)

tools = sa.Table(
    "tools",
    metadata,
    sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
    sa.Column("name", sa.String(200), nullable=False, unique=True),
    # the marker's tool definition (NDI .rom) path and the TCP in the flange, as given
    sa.Column("definition", sa.String(1000)),
    sa.Column("tcp_in_flange", sa.String(200)),
    sa.Column("created_utc", sa.String(40), nullable=False),
)

calibrations = sa.Table(
    "calibrations",
    metadata,
    sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
    sa.Column("content_sha256", sa.String(64), nullable=False, unique=True),
    sa.Column("path", sa.String(2000), nullable=False),
    sa.Column("robot_id", sa.Integer, sa.ForeignKey("robots.id")),
    sa.Column("tracker_id", sa.Integer, sa.ForeignKey("trackers.id")),
    sa.Column("tool_id", sa.Integer, sa.ForeignKey("tools.id")),
    sa.Column("method", sa.String(50), nullable=False),
    sa.Column("grade", sa.String(20)),
    sa.Column("expected_error_mm", sa.Float),
    sa.Column("simulated", sa.Boolean),
    sa.Column("created_utc", sa.String(40), nullable=False),
    sa.Column("recorded_utc", sa.String(40), nullable=False),
    sa.Column("source", sa.String(20), nullable=False),
)

checks = sa.Table(
    "checks",
    metadata,
    sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
    sa.Column("calibration_id", sa.Integer, sa.ForeignKey("calibrations.id"), nullable=False),
    sa.Column("checked_utc", sa.String(40), nullable=False),
    sa.Column("passed", sa.Boolean, nullable=False),
    sa.Column("max_tcp_error_mm", sa.Float, nullable=False),
    sa.Column("max_rotation_error_deg", sa.Float, nullable=False),
    sa.Column("threshold_mm", sa.Float, nullable=False),
    sa.Column("simulated", sa.Boolean),
    sa.Column("source", sa.String(20), nullable=False),
    # the whole check record (spacecal.check schema), so nothing it said is lost
    sa.Column("record_json", sa.Text, nullable=False),
    sa.UniqueConstraint("calibration_id", "checked_utc", "record_json", name="one_row_per_check"),
)


workspaces = sa.Table(
    "workspaces",
    metadata,
    # the station's calibrations in progress, so that they survive a restart with the ids their
    # links carry (never reused: SQLite's AUTOINCREMENT, PostgreSQL's sequence)
    sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
    sa.Column("robot_id", sa.Integer, sa.ForeignKey("robots.id"), nullable=False),
    sa.Column("tracker_id", sa.Integer, sa.ForeignKey("trackers.id"), nullable=False),
    sa.Column("tool_id", sa.Integer, sa.ForeignKey("tools.id")),
    sa.Column("folder", sa.String(2000), nullable=False, unique=True),
    sa.Column("rom", sa.String(1000)),
    sa.Column("created_utc", sa.String(40), nullable=False),
    sqlite_autoincrement=True,
)


def _create_version_1(connection: sa.Connection) -> None:
    """Version 1: robots, trackers, tools, calibrations, checks."""
    for table in (robots, trackers, tools, calibrations, checks):
        table.create(connection)


def _create_version_2(connection: sa.Connection) -> None:
    """Version 2: the station's workspaces."""
    workspaces.create(connection)


#: Columns added to the devices' tables after version 1: (table, column).
RETIRED_COLUMNS = (("robots", "retired_utc"), ("trackers", "retired_utc"))


def _create_version_3(connection: sa.Connection) -> None:
    """Version 3: robots and trackers can be retired (``retired_utc``).

    Version 1 creates the tables as this module defines them now, so a record made by this code
    has the column already; one made by an older spacecal gets it here (``ALTER TABLE ... ADD
    COLUMN``, which SQLite and PostgreSQL both take for a nullable column)."""
    inspector = sa.inspect(connection)
    for table, column in RETIRED_COLUMNS:
        if column not in {c["name"] for c in inspector.get_columns(table)}:
            connection.execute(sa.text(f"ALTER TABLE {table} ADD COLUMN {column} VARCHAR(40)"))


#: The migrations, oldest first: ``MIGRATIONS[k]`` brings the record from version k to k + 1.
MIGRATIONS: list[Callable[[sa.Connection], None]] = [_create_version_1, _create_version_2, _create_version_3]
#: The version this code writes.
CURRENT_VERSION = len(MIGRATIONS)


def stored_version(connection: sa.Connection) -> int:
    """The record's schema version (0 for an empty database)."""
    if not sa.inspect(connection).has_table("schema_version"):
        return 0
    value = connection.execute(sa.select(sa.func.max(schema_version.c.version))).scalar()
    return int(value or 0)


def migrate(engine: sa.Engine, now_utc: str) -> int:
    """Bring the record to :data:`CURRENT_VERSION`, one migration per transaction; returns the
    version it started from.

    Raises
    ------
    InvalidInputError
        The record was written by a newer spacecal (a version this code does not know).
    """
    with engine.begin() as connection:
        if not sa.inspect(connection).has_table("schema_version"):
            schema_version.create(connection)
        start = stored_version(connection)
    if start > CURRENT_VERSION:
        raise InvalidInputError(
            f"the calibration record is at schema version {start}, newer than this spacecal's "
            f"{CURRENT_VERSION}; update spacecal"
        )
    for version in range(start, CURRENT_VERSION):
        with engine.begin() as connection:
            MIGRATIONS[version](connection)
            connection.execute(sa.insert(schema_version).values(version=version + 1, applied_utc=now_utc))
    return start
