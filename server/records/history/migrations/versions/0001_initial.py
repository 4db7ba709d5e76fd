"""The first schema: events, acknowledgements, tool lives (issue 21).

Revision ID: 0001
Revises: (none)
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0001"
down_revision: str | None = None
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "events",
        sa.Column("seq", sa.Integer, primary_key=True, autoincrement=True),
        sa.Column("id", sa.String(64), nullable=False),
        sa.Column("kind", sa.String(32), nullable=False),
        sa.Column("action", sa.String(16), nullable=False),
        sa.Column("t", sa.Float, nullable=False),
        sa.Column("tool", sa.Integer, nullable=False),
        sa.Column("program", sa.String(256), nullable=False),
        sa.Column("line", sa.Integer, nullable=False),
        sa.Column("part", sa.Integer, nullable=False),
        sa.Column("value", sa.Float, nullable=True),
        sa.Column("limit", sa.Float, nullable=True),
        sa.Column("unit", sa.String(32), nullable=False),
        sa.Column("message", sa.Text, nullable=False),
        sa.Column("machine", sa.String(128), nullable=False),
        sa.Column("received_wall", sa.Float, nullable=False),
        sa.PrimaryKeyConstraint("seq", name="pk_events"),
        sa.UniqueConstraint("id", name="uq_events_id"),
    )
    op.create_index("ix_events_kind", "events", ["kind"])
    op.create_index("ix_events_tool", "events", ["tool"])
    op.create_index("ix_events_received_wall", "events", ["received_wall"])
    op.create_table(
        "acknowledgements",
        sa.Column("event_id", sa.String(64), nullable=False),
        sa.Column("by", sa.String(128), nullable=False),
        sa.Column("wall", sa.Float, nullable=False),
        sa.PrimaryKeyConstraint("event_id", name="pk_acknowledgements"),
        sa.ForeignKeyConstraint(
            ["event_id"], ["events.id"], name="fk_acknowledgements_event_id_events"
        ),
    )
    op.create_table(
        "tool_life",
        sa.Column("seq", sa.Integer, primary_key=True, autoincrement=True),
        sa.Column("machine", sa.String(128), nullable=False),
        sa.Column("tool", sa.Integer, nullable=False),
        sa.Column("tool_index", sa.Integer, nullable=True),
        sa.Column("start_t", sa.Float, nullable=True),
        sa.Column("end_t", sa.Float, nullable=False),
        sa.Column("start_wall", sa.Float, nullable=True),
        sa.Column("end_wall", sa.Float, nullable=False),
        sa.Column("wear_at_change_mm", sa.Float, nullable=True),
        sa.Column("wear_true_mm", sa.Float, nullable=True),
        sa.Column("wear_true_share", sa.Float, nullable=True),
        sa.Column("cause", sa.String(32), nullable=False),
        sa.PrimaryKeyConstraint("seq", name="pk_tool_life"),
    )
    op.create_index("ix_tool_life_tool", "tool_life", ["tool"])


def downgrade() -> None:
    op.drop_index("ix_tool_life_tool", "tool_life")
    op.drop_table("tool_life")
    op.drop_table("acknowledgements")
    op.drop_index("ix_events_received_wall", "events")
    op.drop_index("ix_events_tool", "events")
    op.drop_index("ix_events_kind", "events")
    op.drop_table("events")
