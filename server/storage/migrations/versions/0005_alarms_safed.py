"""Alarms, and the pass state ``safed`` (the vehicle safed itself during the pass).

Revision ID: 0005
Revises: 0004
Create Date: 2026-12-01

``alarms``: one row per alarm (a quantity's channel in a band of its limits, or the
vehicle's safing), its worst and current severity, acknowledgement and timeline (JSON). The
passes' state check gains ``safed``.

On SQLite a CHECK constraint changes only by rebuilding the table, and ``commands``,
``telemetry_frames``, ``events`` and ``analysis_results`` hold foreign keys to ``passes``.
Alembic's batch mode (copy into a new table, drop the old one, rename the copy) fails there
on a database that holds commands: with ``foreign_keys = ON`` the drop deletes every pass
under its children (an immediate violation), and ``foreign_keys`` cannot be turned off
inside the migration's transaction. So the rebuild here defers the foreign keys for the
transaction (``PRAGMA defer_foreign_keys``, reset at commit) and puts the rows back into a
table named ``passes`` from a plain copy: the drop counts each orphaned child as a pending
violation and re-inserting its pass settles it, so the commit checks that every child
found its pass again. Indexes and constraint names are those of the models.
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op
from sqlalchemy.dialects import postgresql

revision: str = "0005"
down_revision: str | Sequence[str] | None = "0004"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

UUID = sa.Uuid(as_uuid=False)
JSON_DOC = sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), "postgresql")

_OLD_STATES = ("scheduled", "aos", "running", "los", "complete", "aborted")
_NEW_STATES = (*_OLD_STATES, "safed")
_SEVERITIES = "('watch', 'warning', 'distress', 'critical', 'severe')"
#: Every column of ``passes`` at this revision (0001, then 0002's telemetry window).
_PASS_COLUMNS = (
    "id, name, plan_id, aos_time_ns, los_time_ns, relay, state, state_reason, epoch_ns, "
    "created_at_ns, updated_at_ns, version, telemetry_start_ns, telemetry_end_ns"
)
_COPY = "_alembic_passes_0005"


def _states(values: tuple[str, ...]) -> str:
    return "state IN (" + ", ".join(f"'{v}'" for v in values) + ")"


def _ns(name: str, *, nullable: bool = False) -> sa.Column[int]:
    return sa.Column(name, sa.BigInteger(), nullable=nullable)


def _create_passes(states: tuple[str, ...]) -> None:
    op.create_table(
        "passes",
        sa.Column("id", UUID, nullable=False),
        sa.Column("name", sa.String(length=128), nullable=False),
        sa.Column("plan_id", UUID, nullable=False),
        _ns("aos_time_ns"),
        _ns("los_time_ns"),
        sa.Column("relay", sa.String(length=64), nullable=False),
        sa.Column("state", sa.String(length=16), nullable=False),
        sa.Column("state_reason", sa.Text(), nullable=True),
        _ns("epoch_ns", nullable=True),
        _ns("created_at_ns"),
        _ns("updated_at_ns"),
        sa.Column("version", sa.BigInteger(), nullable=False),
        _ns("telemetry_start_ns", nullable=True),
        _ns("telemetry_end_ns", nullable=True),
        sa.CheckConstraint(_states(states), name=op.f("ck_passes_state")),
        sa.CheckConstraint("los_time_ns >= aos_time_ns", name=op.f("ck_passes_window")),
        sa.ForeignKeyConstraint(["plan_id"], ["plans.id"], name=op.f("fk_passes_plan_id_plans")),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_passes")),
    )
    op.create_index("ix_passes_aos_time_ns", "passes", ["aos_time_ns"])
    op.create_index("ix_passes_plan_id", "passes", ["plan_id"])
    op.create_index("ix_passes_state", "passes", ["state"])


def _pass_states(states: tuple[str, ...]) -> None:
    """The passes' state check allows ``states`` (see the module docstring for SQLite)."""
    if op.get_bind().dialect.name != "sqlite":
        op.drop_constraint(op.f("ck_passes_state"), "passes", type_="check")
        op.create_check_constraint(op.f("ck_passes_state"), "passes", _states(states))
        return
    op.execute("PRAGMA defer_foreign_keys = ON")
    op.execute(f"CREATE TABLE {_COPY} AS SELECT {_PASS_COLUMNS} FROM passes")
    op.drop_table("passes")
    _create_passes(states)
    op.execute(f"INSERT INTO passes ({_PASS_COLUMNS}) SELECT {_PASS_COLUMNS} FROM {_COPY}")
    op.drop_table(_COPY)


def upgrade() -> None:
    _pass_states(_NEW_STATES)
    op.create_table(
        "alarms",
        sa.Column("id", UUID, nullable=False),
        sa.Column("pass_id", UUID, nullable=True),
        sa.Column("quantity", sa.String(length=64), nullable=False),
        sa.Column("channel", sa.String(length=32), nullable=False),
        sa.Column("label", sa.String(length=128), nullable=False),
        sa.Column("unit", sa.String(length=16), nullable=False),
        sa.Column("direction", sa.String(length=8), nullable=False),
        sa.Column("source", sa.String(length=16), nullable=False),
        sa.Column("severity", sa.String(length=16), nullable=False),
        sa.Column("current_severity", sa.String(length=16), nullable=True),
        sa.Column("state", sa.String(length=16), nullable=False),
        sa.Column("acknowledged", sa.Boolean(), nullable=False),
        sa.Column("acknowledged_by", sa.String(length=128), nullable=True),
        _ns("acknowledged_time_ns", nullable=True),
        sa.Column("comment", sa.Text(), nullable=True),
        sa.Column("limit_value", sa.Double(), nullable=True),
        sa.Column("trigger_value", sa.Double(), nullable=True),
        sa.Column("worst_value", sa.Double(), nullable=True),
        sa.Column("last_value", sa.Double(), nullable=True),
        sa.Column("count", sa.BigInteger(), nullable=False),
        _ns("raised_frame_seq", nullable=True),
        _ns("raised_generation_time_ns", nullable=True),
        _ns("raised_time_ns"),
        _ns("updated_time_ns"),
        _ns("cleared_generation_time_ns", nullable=True),
        _ns("cleared_time_ns", nullable=True),
        sa.Column("timeline", JSON_DOC, nullable=False),
        sa.Column("detail", sa.Text(), nullable=True),
        sa.CheckConstraint(f"severity IN {_SEVERITIES}", name=op.f("ck_alarms_severity")),
        sa.CheckConstraint(
            f"current_severity IS NULL OR current_severity IN {_SEVERITIES}",
            name=op.f("ck_alarms_current_severity"),
        ),
        sa.CheckConstraint("source IN ('limit', 'vehicle')", name=op.f("ck_alarms_source")),
        sa.CheckConstraint("state IN ('triggered', 'cleared')", name=op.f("ck_alarms_state")),
        sa.CheckConstraint("direction IN ('high', 'low')", name=op.f("ck_alarms_direction")),
        sa.ForeignKeyConstraint(["pass_id"], ["passes.id"], name=op.f("fk_alarms_pass_id_passes")),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_alarms")),
    )
    op.create_index("ix_alarms_raised_time_ns", "alarms", ["raised_time_ns"])
    op.create_index("ix_alarms_pass_id_raised_time_ns", "alarms", ["pass_id", "raised_time_ns"])
    op.create_index("ix_alarms_acknowledged_state", "alarms", ["acknowledged", "state"])


def downgrade() -> None:
    op.drop_table("alarms")
    # a pass the vehicle's safing ended was ended: aborted, the reason saying why
    op.execute(
        "UPDATE passes SET state = 'aborted', "
        "state_reason = 'safed: ' || COALESCE(state_reason, '') WHERE state = 'safed'"
    )
    _pass_states(_OLD_STATES)
