"""The history's tables (SQLAlchemy Core): events, their acknowledgements, tool lives.

These are the tables as the code uses them; the database gets them from the migration
scripts (:mod:`server.records.history.migrations`), never from ``create_all``. A change
here needs a new migration script (``tests/records/test_history.py`` checks that the
migrated database matches these tables).

Times: ``t``, ``start_t``, ``end_t`` are the source's (simulated) time [s]; ``*_wall``
are Unix seconds of the host. Missing numbers are NULL (an event's NaN value or limit,
a tool whose start the history did not see).
"""

from __future__ import annotations

from sqlalchemy import (
    Column,
    Float,
    ForeignKey,
    Integer,
    MetaData,
    String,
    Table,
    Text,
)

#: constraint and index names the same on every database (Alembic needs them to alter)
NAMING = {
    "ix": "ix_%(column_0_label)s",
    "uq": "uq_%(table_name)s_%(column_0_name)s",
    "fk": "fk_%(table_name)s_%(column_0_name)s_%(referred_table_name)s",
    "pk": "pk_%(table_name)s",
}

metadata = MetaData(naming_convention=NAMING)

#: every field of :class:`~server.records.monitor_events.MonitorEvent`, and when the
#: history received it; ``seq`` orders events received in the same wall second
events = Table(
    "events",
    metadata,
    Column("seq", Integer, primary_key=True, autoincrement=True),
    Column("id", String(64), nullable=False, unique=True),
    Column("kind", String(32), nullable=False, index=True),
    Column("action", String(16), nullable=False),
    Column("t", Float, nullable=False),
    Column("tool", Integer, nullable=False, index=True),
    Column("program", String(256), nullable=False),
    Column("line", Integer, nullable=False),
    Column("part", Integer, nullable=False),
    Column("value", Float, nullable=True),
    Column("limit", Float, nullable=True),
    Column("unit", String(32), nullable=False),
    Column("message", Text, nullable=False),
    Column("machine", String(128), nullable=False),
    Column("received_wall", Float, nullable=False, index=True),
)

#: at most one acknowledgement per event (a second one is answered with the first)
acknowledgements = Table(
    "acknowledgements",
    metadata,
    Column("event_id", String(64), ForeignKey("events.id"), primary_key=True),
    Column("by", String(128), nullable=False),
    Column("wall", Float, nullable=False),
)

#: one row per tool taken out of the spindle: from its start to its change, and why
tool_life = Table(
    "tool_life",
    metadata,
    Column("seq", Integer, primary_key=True, autoincrement=True),
    Column("machine", String(128), nullable=False),
    Column("tool", Integer, nullable=False, index=True),
    Column("tool_index", Integer, nullable=True),
    Column("start_t", Float, nullable=True),
    Column("end_t", Float, nullable=False),
    Column("start_wall", Float, nullable=True),
    Column("end_wall", Float, nullable=False),
    Column("wear_at_change_mm", Float, nullable=True),
    Column("wear_true_mm", Float, nullable=True),
    Column("wear_true_share", Float, nullable=True),
    Column("cause", String(32), nullable=False),
    # the flank wear measured at the change, entered over REST (migration 0002)
    Column("wear_measured_mm", Float, nullable=True),
)
