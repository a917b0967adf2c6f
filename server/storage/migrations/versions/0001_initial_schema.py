"""Initial schema: plans, passes, commands, telemetry frames, events, analysis results.

Revision ID: 0001
Revises:
Create Date: 2026-11-22

Types are written out here, not imported from ``models.py``: a revision stays what it was
when the models move on.
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op
from sqlalchemy.dialects import postgresql

revision: str = "0001"
down_revision: str | Sequence[str] | None = None
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

UUID = sa.Uuid(as_uuid=False)
BIGINT_KEY = sa.BigInteger().with_variant(sa.INTEGER(), "sqlite")
JSON_DOC = sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), "postgresql")

TELEMETRY_FLOATS_1 = (
    *(f"j{i}" for i in range(1, 7)),
    *(f"t{i}" for i in range(1, 7)),
    *("qx", "qy", "qz", "qw", "wx", "wy", "wz"),
    *("ws1", "ws2", "ws3", "hw1", "hw2", "hw3"),
)
TELEMETRY_FLOATS_2 = ("tqx", "tqy", "tqz", "tqw")


def _ns(name: str, *, nullable: bool = False) -> sa.Column[int]:
    return sa.Column(name, sa.BigInteger(), nullable=nullable)


def upgrade() -> None:
    op.create_table(
        "plans",
        sa.Column("id", UUID, nullable=False),
        sa.Column("experiment", sa.String(length=64), nullable=False),
        sa.Column("parameters", JSON_DOC, nullable=False),
        sa.Column("document", sa.Text(), nullable=False),
        sa.Column("duration_s", sa.Double(), nullable=False),
        sa.Column("n_commands", sa.BigInteger(), nullable=False),
        _ns("created_at_ns"),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_plans")),
    )
    op.create_index("ix_plans_created_at_ns", "plans", ["created_at_ns"])

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
        sa.CheckConstraint(
            "state IN ('scheduled', 'aos', 'running', 'los', 'complete', 'aborted')",
            name=op.f("ck_passes_state"),
        ),
        sa.CheckConstraint("los_time_ns >= aos_time_ns", name=op.f("ck_passes_window")),
        sa.ForeignKeyConstraint(["plan_id"], ["plans.id"], name=op.f("fk_passes_plan_id_plans")),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_passes")),
    )
    op.create_index("ix_passes_aos_time_ns", "passes", ["aos_time_ns"])
    op.create_index("ix_passes_plan_id", "passes", ["plan_id"])
    op.create_index("ix_passes_state", "passes", ["state"])

    op.create_table(
        "commands",
        sa.Column("pass_id", UUID, nullable=False),
        sa.Column("seq", sa.BigInteger(), nullable=False),
        sa.Column("kind", sa.String(length=16), nullable=False),
        _ns("execute_time_ns"),
        sa.Column("payload", JSON_DOC, nullable=False),
        sa.Column("stage", sa.String(length=16), nullable=False),
        sa.Column("reject_reason", sa.String(length=32), nullable=True),
        _ns("queued_at_ns"),
        *(
            _ns(f"{stage}_at_ns", nullable=True)
            for stage in ("released", "sent", "received", "executed", "rejected", "expired")
        ),
        sa.CheckConstraint("kind IN ('joints', 'acs')", name=op.f("ck_commands_kind")),
        sa.CheckConstraint(
            "stage IN ('queued', 'released', 'sent', 'received', 'executed', 'rejected', "
            "'expired')",
            name=op.f("ck_commands_stage"),
        ),
        sa.ForeignKeyConstraint(
            ["pass_id"], ["passes.id"], name=op.f("fk_commands_pass_id_passes")
        ),
        sa.PrimaryKeyConstraint("pass_id", "seq", name=op.f("pk_commands")),
    )
    op.create_index(
        "ix_commands_pass_id_stage_execute_time_ns",
        "commands",
        ["pass_id", "stage", "execute_time_ns"],
    )
    op.create_index(
        "ix_commands_pass_id_execute_time_ns", "commands", ["pass_id", "execute_time_ns"]
    )

    op.create_table(
        "telemetry_frames",
        sa.Column("pass_id", UUID, nullable=False),
        sa.Column("seq", sa.BigInteger(), nullable=False),
        _ns("generation_time_ns"),
        _ns("reception_time_ns"),
        *(sa.Column(name, sa.Double(), nullable=False) for name in TELEMETRY_FLOATS_1),
        sa.Column("acs_mode", sa.String(length=16), nullable=False),
        *(sa.Column(name, sa.Double(), nullable=False) for name in TELEMETRY_FLOATS_2),
        sa.Column("acs_feedforward", sa.Boolean(), nullable=False),
        sa.Column("buffer_queued", sa.BigInteger(), nullable=False),
        _ns("buffer_next_execute_time_ns", nullable=True),
        sa.Column("buffer_last_executed_seq", sa.BigInteger(), nullable=False),
        sa.ForeignKeyConstraint(
            ["pass_id"], ["passes.id"], name=op.f("fk_telemetry_frames_pass_id_passes")
        ),
        # Holds the hypertable partitioning column (see models.TelemetryFrameRecord).
        sa.PrimaryKeyConstraint(
            "pass_id", "seq", "generation_time_ns", name=op.f("pk_telemetry_frames")
        ),
    )
    op.create_index(
        "ix_telemetry_frames_pass_id_generation_time_ns",
        "telemetry_frames",
        ["pass_id", "generation_time_ns"],
    )

    op.create_table(
        "events",
        sa.Column("id", BIGINT_KEY, autoincrement=True, nullable=False),
        sa.Column("pass_id", UUID, nullable=True),
        _ns("time_ns"),
        sa.Column("kind", sa.String(length=64), nullable=False),
        sa.Column("actor", sa.String(length=128), nullable=False),
        sa.Column("detail", JSON_DOC, nullable=False),
        sa.ForeignKeyConstraint(["pass_id"], ["passes.id"], name=op.f("fk_events_pass_id_passes")),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_events")),
    )
    op.create_index("ix_events_time_ns", "events", ["time_ns"])
    op.create_index("ix_events_pass_id_time_ns", "events", ["pass_id", "time_ns"])
    op.create_index("ix_events_kind_time_ns", "events", ["kind", "time_ns"])

    op.create_table(
        "analysis_results",
        sa.Column("id", BIGINT_KEY, autoincrement=True, nullable=False),
        sa.Column("pass_id", UUID, nullable=False),
        sa.Column("kind", sa.String(length=64), nullable=False),
        _ns("created_at_ns"),
        sa.Column("result", JSON_DOC, nullable=False),
        sa.ForeignKeyConstraint(
            ["pass_id"], ["passes.id"], name=op.f("fk_analysis_results_pass_id_passes")
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_analysis_results")),
    )
    op.create_index(
        "ix_analysis_results_pass_id_kind_created_at_ns",
        "analysis_results",
        ["pass_id", "kind", "created_at_ns"],
    )


def downgrade() -> None:
    # Indexes go with their tables; children before parents.
    for table in ("analysis_results", "events", "telemetry_frames", "commands", "passes", "plans"):
        op.drop_table(table)
