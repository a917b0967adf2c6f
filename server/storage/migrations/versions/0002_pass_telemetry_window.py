"""Passes keep their telemetry window, so a restarted ground still files late frames.

Revision ID: 0002
Revises: 0001
Create Date: 2026-11-22

``telemetry_start_ns`` / ``telemetry_end_ns`` (onboard clock): frames generated in
``[start, end)`` belong to the pass; ``end`` is NULL while the window is open.
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0002"
down_revision: str | Sequence[str] | None = "0001"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("passes") as batch:
        batch.add_column(sa.Column("telemetry_start_ns", sa.BigInteger(), nullable=True))
        batch.add_column(sa.Column("telemetry_end_ns", sa.BigInteger(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("passes") as batch:
        batch.drop_column("telemetry_end_ns")
        batch.drop_column("telemetry_start_ns")
