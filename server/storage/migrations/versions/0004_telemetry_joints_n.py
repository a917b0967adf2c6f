"""Telemetry of robots with more joints than ETS-VII's six, and each plan's joint count.

Revision ID: 0004
Revises: 0003
Create Date: 2026-11-25

``telemetry_frames`` gains ``j7..j12`` and ``t7..t12`` (measured joints and servo targets,
rad; NULL where the pass's robot has fewer joints: every frame stored before this revision
is ETS-VII's). ``plans.n_joints`` is the robot's joint count, which fixes the telemetry
layout of the plan's passes (``telemetry.layout.FrameLayout``); plans stored before this
revision are ETS-VII's: 6.
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0004"
down_revision: str | Sequence[str] | None = "0003"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

#: The joints added: 7..12 (server.storage.models.MAX_STORED_JOINTS), fixed here as they
#: were at this revision.
_JOINTS = range(7, 13)
_COLUMNS = [f"j{i}" for i in _JOINTS] + [f"t{i}" for i in _JOINTS]


def upgrade() -> None:
    with op.batch_alter_table("telemetry_frames") as batch:
        for name in _COLUMNS:
            batch.add_column(sa.Column(name, sa.Double(), nullable=True))
    with op.batch_alter_table("plans") as batch:
        batch.add_column(sa.Column("n_joints", sa.Integer(), nullable=False, server_default="6"))


def downgrade() -> None:
    # ALTER TABLE ... DROP COLUMN, not a batch rebuild: SQLite (3.35 and later) drops a plain
    # column in place, where rebuilding ``plans`` would break the passes' foreign keys.
    op.drop_column("plans", "n_joints")
    for name in reversed(_COLUMNS):
        op.drop_column("telemetry_frames", name)
