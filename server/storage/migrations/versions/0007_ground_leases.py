"""The command authority over a vehicle: one lease row per vehicle, with its fencing token.

Revision ID: 0007
Revises: 0006
Create Date: 2026-12-06

``ground_leases``: which ground holds the command authority (``holder``), the fencing token
every write of the command path checks (``token``, raised at each acquisition), and the
database-clock times it was acquired, last renewed and expires at (server/storage/lease.py).
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0007"
down_revision: str | Sequence[str] | None = "0006"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "ground_leases",
        sa.Column("name", sa.String(64), nullable=False),
        sa.Column("holder", sa.String(128), nullable=False),
        sa.Column("token", sa.BigInteger(), nullable=False),
        sa.Column("acquired_s", sa.Double(), nullable=False),
        sa.Column("renewed_s", sa.Double(), nullable=False),
        sa.Column("expires_s", sa.Double(), nullable=False),
        sa.PrimaryKeyConstraint("name", name=op.f("pk_ground_leases")),
    )


def downgrade() -> None:
    op.drop_table("ground_leases")
