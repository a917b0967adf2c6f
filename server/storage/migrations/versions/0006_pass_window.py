"""Passes keep the computed contact window they were scheduled in.

Revision ID: 0006
Revises: 0005
Create Date: 2026-11-27

``window_mission`` (the mission's name) and ``window_detail`` (JSON: relay, AOS and LOS in ns of
UTC, margins, ranges, light times, the mission file's hash), both NULL for a pass whose
window was given by hand (every pass before this revision). Adding nullable columns needs
no rebuild of ``passes`` on SQLite (``ALTER TABLE ... ADD COLUMN``), so its children's
foreign keys are not touched. (Not ``window``: a reserved word of PostgreSQL.)
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op
from sqlalchemy.dialects import postgresql

revision: str = "0006"
down_revision: str | Sequence[str] | None = "0005"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

JSON_DOC = sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), "postgresql")


def upgrade() -> None:
    op.add_column("passes", sa.Column("window_mission", sa.String(64), nullable=True))
    op.add_column("passes", sa.Column("window_detail", JSON_DOC, nullable=True))


def downgrade() -> None:
    # SQLite drops a column in place (3.35+) when nothing refers to it, as here.
    op.drop_column("passes", "window_detail")
    op.drop_column("passes", "window_mission")
