"""Alembic builds exactly the schema the models describe, on SQLite and PostgreSQL."""

from __future__ import annotations

import pytest
from alembic import command
from sqlalchemy import CheckConstraint, Engine, inspect, text
from sqlalchemy.exc import IntegrityError

from server.storage.db import alembic_config, schema_diff, upgrade
from server.storage.models import Base

TABLES = {
    "plans",
    "passes",
    "commands",
    "telemetry_frames",
    "ground_leases",
    "events",
    "analysis_results",
    "alarms",
}


def test_migrations_create_every_table(empty_engine: Engine) -> None:
    assert set(inspect(empty_engine).get_table_names()) == set()
    upgrade(empty_engine)
    assert set(inspect(empty_engine).get_table_names()) == TABLES | {"alembic_version"}
    assert set(Base.metadata.tables) == TABLES
    with empty_engine.connect() as conn:
        assert conn.scalar(text("SELECT version_num FROM alembic_version")) == "0007"


def test_upgrade_is_idempotent(engine: Engine) -> None:
    upgrade(engine)  # already at head: nothing to do, nothing fails
    assert schema_diff(engine) == []


def test_models_and_migrations_agree(engine: Engine) -> None:
    assert schema_diff(engine) == []


def test_the_comparison_would_see_a_difference(engine: Engine) -> None:
    with engine.begin() as conn:
        conn.execute(text("DROP INDEX ix_events_kind_time_ns"))
    diff = schema_diff(engine)
    assert [d[0] for d in diff] == ["add_index"]
    assert diff[0][1].name == "ix_events_kind_time_ns"


def test_check_constraints_agree(engine: Engine) -> None:
    # Alembic's autogenerate does not compare CHECK constraints: compare their names here.
    inspector = inspect(engine)
    for table in Base.metadata.sorted_tables:
        in_models = {c.name for c in table.constraints if isinstance(c, CheckConstraint)}
        in_database = {c["name"] for c in inspector.get_check_constraints(table.name)}
        assert in_database == in_models, table.name


def test_primary_keys_and_time_index_of_telemetry(engine: Engine) -> None:
    inspector = inspect(engine)
    pk = inspector.get_pk_constraint("telemetry_frames")
    # The hypertable partitioning column is part of every unique key (TimescaleDB's rule).
    assert pk["constrained_columns"] == ["pass_id", "seq", "generation_time_ns"]
    indexes = {i["name"]: i["column_names"] for i in inspector.get_indexes("telemetry_frames")}
    assert indexes["ix_telemetry_frames_pass_id_generation_time_ns"] == [
        "pass_id",
        "generation_time_ns",
    ]
    assert inspector.get_pk_constraint("commands")["constrained_columns"] == ["pass_id", "seq"]


def test_downgrade_removes_everything_and_upgrade_rebuilds(engine: Engine) -> None:
    with engine.begin() as conn:
        command.downgrade(alembic_config(conn), "base")
    assert set(inspect(engine).get_table_names()) <= {"alembic_version"}
    upgrade(engine)
    assert schema_diff(engine) == []


def test_sqlite_connections_get_wal_and_foreign_keys(engine: Engine) -> None:
    if engine.dialect.name != "sqlite":
        pytest.skip("SQLite pragmas")
    with engine.connect() as conn:
        assert conn.exec_driver_sql("PRAGMA journal_mode").scalar() == "wal"
        assert conn.exec_driver_sql("PRAGMA foreign_keys").scalar() == 1
        assert conn.exec_driver_sql("PRAGMA busy_timeout").scalar() == 10000


def _insert_plan_and_pass(engine: Engine) -> str:
    """A plan and a complete pass 'p1' of it, in plain SQL (any revision); the pass id."""
    # 32 hex digits: SQLite's stored form of a UUID, and a valid uuid literal on PostgreSQL.
    plan_id, pass_id = "0" * 31 + "1", "0" * 31 + "2"
    with engine.begin() as conn:
        conn.execute(
            text(
                "INSERT INTO plans (id, experiment, parameters, document, duration_s, "
                "n_commands, created_at_ns) VALUES (:id, 'ptp', '{}', '{}', 1.0, 4, 1)"
            ),
            {"id": plan_id},
        )
        conn.execute(
            text(
                "INSERT INTO passes (id, name, plan_id, aos_time_ns, los_time_ns, relay, state, "
                "created_at_ns, updated_at_ns, version) VALUES "
                "(:id, 'p1', :plan, 10, 20, 'TDRS', 'complete', 1, 1, 1)"
            ),
            {"id": pass_id, "plan": plan_id},
        )
    return pass_id


def test_0002_keeps_the_passes_of_0001(empty_engine: Engine) -> None:
    upgrade(empty_engine, "0001")
    _insert_plan_and_pass(empty_engine)
    upgrade(empty_engine)
    with empty_engine.connect() as conn:
        row = conn.execute(
            text("SELECT name, state, telemetry_start_ns, telemetry_end_ns FROM passes")
        ).one()
    assert tuple(row) == ("p1", "complete", None, None)
    assert schema_diff(empty_engine) == []


def test_0003_counts_one_transmission_for_each_command_sent_before_it(
    empty_engine: Engine,
) -> None:
    upgrade(empty_engine, "0002")
    pass_id = _insert_plan_and_pass(empty_engine)
    with empty_engine.begin() as conn:
        for seq, stage, sent in ((0, "executed", 5), (1, "expired", None)):
            conn.execute(
                text(
                    "INSERT INTO commands (pass_id, seq, kind, execute_time_ns, payload, "
                    "stage, queued_at_ns, sent_at_ns) VALUES "
                    "(:pass, :seq, 'joints', 100, '{}', :stage, 1, :sent)"
                ),
                {"pass": pass_id, "seq": seq, "stage": stage, "sent": sent},
            )
    upgrade(empty_engine)
    with empty_engine.begin() as conn:
        rows = conn.execute(
            text("SELECT seq, stage, transmissions, cancelled_at_ns FROM commands ORDER BY seq")
        ).all()
        assert [tuple(r) for r in rows] == [(0, "executed", 1, None), (1, "expired", 0, None)]
        # the new stage is allowed
        conn.execute(text("UPDATE commands SET stage = 'cancelled' WHERE seq = 1"))
    assert schema_diff(empty_engine) == []


def test_0004_adds_joints_7_to_12_and_counts_six_joints_for_older_plans(
    empty_engine: Engine,
) -> None:
    upgrade(empty_engine, "0003")
    _insert_plan_and_pass(empty_engine)
    upgrade(empty_engine)
    with empty_engine.connect() as conn:
        assert conn.execute(text("SELECT n_joints FROM plans")).scalar_one() == 6
    columns = {c["name"]: c for c in inspect(empty_engine).get_columns("telemetry_frames")}
    for i in range(7, 13):
        assert columns[f"j{i}"]["nullable"] and columns[f"t{i}"]["nullable"]
    assert not columns["j6"]["nullable"]
    assert "j13" not in columns
    assert schema_diff(empty_engine) == []
    with empty_engine.begin() as conn:
        command.downgrade(alembic_config(conn), "0003")
    assert "j7" not in {c["name"] for c in inspect(empty_engine).get_columns("telemetry_frames")}
    assert "n_joints" not in {c["name"] for c in inspect(empty_engine).get_columns("plans")}


def _insert_children(engine: Engine, pass_id: str) -> None:
    """A command, a telemetry frame, an event and an analysis of the pass (revision 0004)."""
    floats = [f"j{i}" for i in range(1, 7)] + [f"t{i}" for i in range(1, 7)]
    floats += ["qx", "qy", "qz", "qw", "wx", "wy", "wz", "ws1", "ws2", "ws3"]
    floats += ["hw1", "hw2", "hw3", "tqx", "tqy", "tqz", "tqw"]
    with engine.begin() as conn:
        conn.execute(
            text(
                "INSERT INTO commands (pass_id, seq, kind, execute_time_ns, payload, stage, "
                "queued_at_ns, transmissions) VALUES "
                "(:pass, 7, 'joints', 100, '{}', 'executed', 1, 1)"
            ),
            {"pass": pass_id},
        )
        conn.execute(
            text(
                f"INSERT INTO telemetry_frames (pass_id, seq, generation_time_ns, "
                f"reception_time_ns, {', '.join(floats)}, acs_mode, acs_feedforward, "
                f"buffer_queued, buffer_last_executed_seq) VALUES (:pass, 3, 50, 60, "
                f"{', '.join('0.5' for _ in floats)}, 'feedback', false, 0, -1)"
            ),
            {"pass": pass_id},
        )
        conn.execute(
            text(
                "INSERT INTO events (pass_id, time_ns, kind, actor, detail) VALUES "
                "(:pass, 5, 'pass_state', 'op', '{}')"
            ),
            {"pass": pass_id},
        )
        conn.execute(
            text(
                "INSERT INTO analysis_results (pass_id, kind, created_at_ns, result) VALUES "
                "(:pass, 'pass_analysis', 5, '{}')"
            ),
            {"pass": pass_id},
        )


def _children(engine: Engine) -> list[tuple[object, ...]]:
    with engine.connect() as conn:
        return [
            tuple(conn.execute(text(q)).one())
            for q in (
                "SELECT seq, stage, transmissions FROM commands",
                "SELECT seq, generation_time_ns, j1 FROM telemetry_frames",
                "SELECT kind, actor FROM events",
                "SELECT kind, created_at_ns FROM analysis_results",
            )
        ]


def _upgraded_with_children(engine: Engine, revision: str) -> tuple[str, list[tuple[object, ...]]]:
    """At ``revision``, a pass and a row of each table that refers to it; then upgraded to
    the head: the pass's id and those rows as they were before the upgrade."""
    upgrade(engine, revision)
    pass_id = _insert_plan_and_pass(engine)
    _insert_children(engine, pass_id)
    before = _children(engine)
    upgrade(engine)
    return pass_id, before


def test_0005_keeps_passes_and_what_refers_to_them_and_allows_safed(
    empty_engine: Engine,
) -> None:
    _, before = _upgraded_with_children(empty_engine, "0004")
    assert schema_diff(empty_engine) == []
    assert _children(empty_engine) == before
    with empty_engine.connect() as conn:
        row = conn.execute(text("SELECT name, state, version FROM passes")).one()
        assert tuple(row) == ("p1", "complete", 1)
        assert conn.execute(text("SELECT count(*) FROM alarms")).scalar_one() == 0
    with empty_engine.begin() as conn:
        conn.execute(text("UPDATE passes SET state = 'safed', state_reason = 'joint3'"))
    # the foreign keys still hold after the rebuild: a command of no pass is refused
    with pytest.raises(IntegrityError), empty_engine.begin() as conn:
        conn.execute(
            text(
                "INSERT INTO commands (pass_id, seq, kind, execute_time_ns, payload, stage, "
                "queued_at_ns) VALUES (:pass, 8, 'joints', 1, '{}', 'queued', 1)"
            ),
            {"pass": "0" * 31 + "9"},
        )
    with pytest.raises(IntegrityError), empty_engine.begin() as conn:
        conn.execute(text("UPDATE passes SET state = 'lost'"))


def test_0005_downgrades_a_safed_pass_to_aborted_and_keeps_the_rest(
    empty_engine: Engine,
) -> None:
    pass_id, before = _upgraded_with_children(empty_engine, "0004")
    with empty_engine.begin() as conn:
        conn.execute(text("UPDATE passes SET state = 'safed', state_reason = 'joint3 red'"))
        conn.execute(
            text(
                "INSERT INTO alarms (id, pass_id, quantity, channel, label, unit, direction, "
                "source, severity, state, acknowledged, count, raised_time_ns, "
                "updated_time_ns, timeline) VALUES ('" + "0" * 31 + "5', :pass, "
                "'vehicle_safing', '', 'vehicle safing', '', 'high', 'vehicle', 'critical', "
                "'triggered', false, 1, 1, 1, '[]')"
            ),
            {"pass": pass_id},
        )
    with empty_engine.begin() as conn:
        command.downgrade(alembic_config(conn), "0004")
    assert "alarms" not in inspect(empty_engine).get_table_names()
    assert _children(empty_engine) == before
    with empty_engine.connect() as conn:
        row = conn.execute(text("SELECT state, state_reason FROM passes")).one()
    assert tuple(row) == ("aborted", "safed: joint3 red")
    with pytest.raises(IntegrityError), empty_engine.begin() as conn:
        conn.execute(text("UPDATE passes SET state = 'safed'"))
    upgrade(empty_engine)
    assert schema_diff(empty_engine) == []


def test_0006_gives_passes_an_empty_window_and_keeps_what_refers_to_them(
    empty_engine: Engine,
) -> None:
    _, before = _upgraded_with_children(empty_engine, "0005")
    assert schema_diff(empty_engine) == []
    assert _children(empty_engine) == before
    with empty_engine.connect() as conn:
        row = conn.execute(
            text("SELECT name, state, window_mission, window_detail FROM passes")
        ).one()
    assert tuple(row) == ("p1", "complete", None, None)
    with empty_engine.begin() as conn:
        conn.execute(
            text("UPDATE passes SET window_mission = 'ets7-1999', window_detail = :doc"),
            {"doc": '{"relay": "TDRS-East"}'},
        )
    with empty_engine.begin() as conn:
        command.downgrade(alembic_config(conn), "0005")
    columns = {c["name"] for c in inspect(empty_engine).get_columns("passes")}
    assert "window_detail" not in columns and "window_mission" not in columns
    assert _children(empty_engine) == before
    upgrade(empty_engine)
    assert schema_diff(empty_engine) == []
