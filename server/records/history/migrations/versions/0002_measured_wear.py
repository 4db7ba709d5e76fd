"""The flank wear measured on a tool at its change (issue 35 item 7): ``tool_life``'s
``wear_measured_mm``, entered over REST (``POST /api/tool-life/vb``).

Revision ID: 0002
Revises: 0001
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0002"
down_revision: str | None = "0001"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.add_column("tool_life", sa.Column("wear_measured_mm", sa.Float, nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("tool_life") as batch:
        batch.drop_column("wear_measured_mm")
