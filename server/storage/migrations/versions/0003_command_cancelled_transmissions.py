"""Commands can be ``cancelled`` (deleted from the onboard schedule by an abort) and count
their transmissions (the windowed uplink retransmits until the vehicle acknowledges).

Revision ID: 0003
Revises: 0002
Create Date: 2026-11-24

``cancelled_at_ns`` (ground clock) is when the ground cancelled the command;
``transmissions`` how many times it went up (0: never sent; a command sent before this
revision went up once: the uplink sent each command once).
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0003"
down_revision: str | Sequence[str] | None = "0002"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

_OLD = "('queued', 'released', 'sent', 'received', 'executed', 'rejected', 'expired')"
_NEW = "('queued', 'released', 'sent', 'received', 'executed', 'rejected', 'expired', 'cancelled')"


def upgrade() -> None:
    with op.batch_alter_table("commands") as batch:
        batch.add_column(sa.Column("cancelled_at_ns", sa.BigInteger(), nullable=True))
        batch.add_column(
            sa.Column("transmissions", sa.Integer(), nullable=False, server_default="0")
        )
        batch.drop_constraint(op.f("ck_commands_stage"), type_="check")
        batch.create_check_constraint(op.f("ck_commands_stage"), f"stage IN {_NEW}")
    # the uplink before this revision sent each command once
    op.execute("UPDATE commands SET transmissions = 1 WHERE sent_at_ns IS NOT NULL")


def downgrade() -> None:
    op.execute(
        "UPDATE commands SET stage = 'expired', expired_at_ns = cancelled_at_ns "
        "WHERE stage = 'cancelled'"
    )
    with op.batch_alter_table("commands") as batch:
        batch.drop_constraint(op.f("ck_commands_stage"), type_="check")
        batch.create_check_constraint(op.f("ck_commands_stage"), f"stage IN {_OLD}")
        batch.drop_column("transmissions")
        batch.drop_column("cancelled_at_ns")
