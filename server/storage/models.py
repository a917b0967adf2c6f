"""The ground service's tables (SQLAlchemy 2 typed ORM), one class per table.

    plans             a plan as uplinked: the planner's JSON document plus searchable summary
    passes            a contact window executing one plan; its state, optimistic-lock version
    commands          the time-tagged commands of a pass, keyed (pass_id, seq), with the time
                      each stage was reached
    telemetry_frames  one row per telemetry frame, one column per value (wide, not EAV)
    events            the audit log: who did what, when, to which pass
    analysis_results  post-pass analysis documents
    alarms            limit alarms and the vehicle's safing alarms, with their timeline
    ground_leases     the command authority over a vehicle: which ground holds it, its
                      fencing token and when it expires (server/storage/lease.py)

Conventions:

- Times are integer nanoseconds (int64), named after the event. ``generation_time_ns`` and
  the acknowledgement stages of a command (``received``/``executed``/``rejected``) are on the
  **onboard** clock, as the spacecraft reports them (``command_ack.onboard_time_ns``);
  every other ``*_ns`` (``created_at_ns``, ``aos_time_ns``, ``reception_time_ns``, ``queued``
  ... ``sent``, ``expired``) is **ground** time, ns since the Unix epoch (UTC).
- Ids are UUIDs (native ``uuid`` on PostgreSQL, 32 hex characters on SQLite); Python sees
  the canonical dashed string.
- JSON is ``jsonb`` on PostgreSQL and JSON text on SQLite.
- Quaternions are scalar-last ``(x, y, z, w)`` as everywhere in the project.

The Alembic migrations in ``migrations/`` create exactly these tables; a test compares them
(autogenerate shows no difference). Change both together.
"""

from __future__ import annotations

from typing import Any

from sqlalchemy import (
    JSON,
    BigInteger,
    Boolean,
    CheckConstraint,
    Double,
    ForeignKey,
    Index,
    Integer,
    MetaData,
    PrimaryKeyConstraint,
    String,
    Text,
    Uuid,
)
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column

from planner.limits import SEVERITIES
from telemetry.alarm import ALARM_DIRECTIONS, ALARM_SOURCES, ALARM_STATES
from telemetry.layout import FrameLayout

__all__ = [
    "ALARM_DIRECTIONS",
    "ALARM_SEVERITIES",
    "ALARM_SOURCES",
    "ALARM_STATES",
    "BUCKET_FIELDS",
    "COMMAND_KINDS",
    "COMMAND_STAGES",
    "MAX_STORED_JOINTS",
    "PASS_STATES",
    "STORAGE_LAYOUT",
    "STORED_WHEELS",
    "TELEMETRY_FIELDS",
    "TELEMETRY_FLOAT_FIELDS",
    "AlarmRecord",
    "AnalysisRecord",
    "Base",
    "CommandRecord",
    "EventRecord",
    "PassRecord",
    "PlanRecord",
    "TelemetryFrameRecord",
    "stored_layout",
]

#: Constraint names are deterministic, so later migrations can address them on every backend.
NAMING_CONVENTION = {
    "ix": "ix_%(table_name)s_%(column_0_N_name)s",
    "uq": "uq_%(table_name)s_%(column_0_N_name)s",
    "ck": "ck_%(table_name)s_%(constraint_name)s",
    "fk": "fk_%(table_name)s_%(column_0_name)s_%(referred_table_name)s",
    "pk": "pk_%(table_name)s",
}

#: ``safed``: the vehicle safed itself during the pass (terminal, like ``aborted``).
PASS_STATES = ("scheduled", "aos", "running", "los", "complete", "aborted", "safed")
COMMAND_KINDS = ("joints", "acs")
#: In the order a command normally goes through them; the last four end it.
COMMAND_STAGES = (
    "queued",
    "released",
    "sent",
    "received",
    "executed",
    "rejected",
    "expired",
    "cancelled",
)

#: Yamcs's five levels, lowest first (planner.limits.Severity, the one declaration).
ALARM_SEVERITIES: tuple[str, ...] = tuple(s.value for s in SEVERITIES)

#: An int64 key that autoincrements: on SQLite only ``INTEGER PRIMARY KEY`` aliases the rowid.
BigIntKey = BigInteger().with_variant(sqlite.INTEGER(), "sqlite")
JSONDocument = JSON().with_variant(postgresql.JSONB(), "postgresql")
UUIDString = Uuid(as_uuid=False)


def _one_of(column: str, values: tuple[str, ...]) -> str:
    # Built from the constants above only, never from user input.
    listed = ", ".join(f"'{v}'" for v in values)
    return f"{column} IN ({listed})"


class Base(DeclarativeBase):
    metadata = MetaData(naming_convention=NAMING_CONVENTION)
    type_annotation_map = {  # noqa: RUF012 (SQLAlchemy reads this class attribute)
        int: BigInteger(),
        float: Double(),
        str: String(),
        dict[str, Any]: JSONDocument,
    }


class PlanRecord(Base):
    """A plan: ``document`` is ``planner.plan.Plan.to_json()``, the rest summarises it."""

    __tablename__ = "plans"

    id: Mapped[str] = mapped_column(UUIDString, primary_key=True)
    experiment: Mapped[str] = mapped_column(String(64))
    parameters: Mapped[dict[str, Any]]
    document: Mapped[str] = mapped_column(Text)
    duration_s: Mapped[float]
    #: Joint commands plus attitude-control commands.
    n_commands: Mapped[int]
    created_at_ns: Mapped[int]
    #: The robot's joint count (``len(initial_joints_rad)``): the layout of the telemetry of
    #: the plan's passes (revision 0004; plans stored before it are ETS-VII's, 6).
    n_joints: Mapped[int] = mapped_column(Integer, server_default="6", default=6)

    __table_args__ = (Index("ix_plans_created_at_ns", "created_at_ns"),)


class PassRecord(Base):
    """A contact window that executes one plan.

    ``version`` is the optimistic lock: every update bumps it, and an update made against an
    older version raises :class:`~server.storage.errors.Conflict`.
    """

    __tablename__ = "passes"

    id: Mapped[str] = mapped_column(UUIDString, primary_key=True)
    name: Mapped[str] = mapped_column(String(128))
    plan_id: Mapped[str] = mapped_column(UUIDString, ForeignKey("plans.id"))
    #: Scheduled acquisition and loss of signal (ground time).
    aos_time_ns: Mapped[int]
    los_time_ns: Mapped[int]
    relay: Mapped[str] = mapped_column(String(64))
    state: Mapped[str] = mapped_column(String(16))
    state_reason: Mapped[str | None] = mapped_column(Text)
    #: Onboard time of the plan's t = 0, once it is known.
    epoch_ns: Mapped[int | None]
    #: Onboard times: frames generated in [start, end) belong to the pass (end NULL: open).
    telemetry_start_ns: Mapped[int | None]
    telemetry_end_ns: Mapped[int | None]
    #: The computed contact window the pass was scheduled in (docs/missions.md): the
    #: mission's name and the window as computed then (relay, AOS and LOS in ns of UTC,
    #: margins, ranges, light times, the mission file's hash); NULL for a hand-given window.
    window_mission: Mapped[str | None] = mapped_column(String(64))
    window_detail: Mapped[dict[str, Any] | None] = mapped_column(JSONDocument)
    created_at_ns: Mapped[int]
    updated_at_ns: Mapped[int]
    version: Mapped[int] = mapped_column()

    __mapper_args__ = {"version_id_col": version}  # noqa: RUF012
    __table_args__ = (
        CheckConstraint(_one_of("state", PASS_STATES), name="state"),
        CheckConstraint("los_time_ns >= aos_time_ns", name="window"),
        Index("ix_passes_aos_time_ns", "aos_time_ns"),
        Index("ix_passes_plan_id", "plan_id"),
        Index("ix_passes_state", "state"),
    )


class CommandRecord(Base):
    """One time-tagged command of a pass and the time it reached each stage.

    ``payload`` holds the kind's own fields of the wire message (``joints_rad`` for
    ``joints``; ``mode``, ``target_quat_orbit_from_base_xyzw``, ``feedforward`` for ``acs``).
    """

    __tablename__ = "commands"

    pass_id: Mapped[str] = mapped_column(UUIDString, ForeignKey("passes.id"))
    seq: Mapped[int]
    kind: Mapped[str] = mapped_column(String(16))
    #: The command's time tag, onboard clock.
    execute_time_ns: Mapped[int]
    payload: Mapped[dict[str, Any]]
    stage: Mapped[str] = mapped_column(String(16))
    reject_reason: Mapped[str | None] = mapped_column(String(32))
    queued_at_ns: Mapped[int]
    released_at_ns: Mapped[int | None]
    sent_at_ns: Mapped[int | None]
    received_at_ns: Mapped[int | None]
    executed_at_ns: Mapped[int | None]
    rejected_at_ns: Mapped[int | None]
    expired_at_ns: Mapped[int | None]
    cancelled_at_ns: Mapped[int | None]
    #: How many times the command went up (the uplink retransmits until acknowledged).
    transmissions: Mapped[int] = mapped_column(Integer, server_default="0", default=0)

    __table_args__ = (
        PrimaryKeyConstraint("pass_id", "seq"),
        CheckConstraint(_one_of("kind", COMMAND_KINDS), name="kind"),
        CheckConstraint(_one_of("stage", COMMAND_STAGES), name="stage"),
        # what to release next, what is still outstanding
        Index("ix_commands_pass_id_stage_execute_time_ns", "pass_id", "stage", "execute_time_ns"),
        Index("ix_commands_pass_id_execute_time_ns", "pass_id", "execute_time_ns"),
    )


#: Joints the archive has columns for (j1..j12, t1..t12); a pass's robot may have fewer
#: (ETS-VII: 6, its j7.. are NULL), not more. Wheel speeds: ws1..ws3, three wheels.
MAX_STORED_JOINTS = 12
STORED_WHEELS = 3
#: Every telemetry column of the table, named by :class:`telemetry.layout.FrameLayout`; a
#: pass uses those of its robot's layout (:func:`stored_layout`).
STORAGE_LAYOUT = FrameLayout(MAX_STORED_JOINTS, STORED_WHEELS)
#: Telemetry float columns. Units: ``j*``/``t*`` measured joints / servo targets (rad);
#: ``qx..qw`` quat_orbit_from_base; ``wx..wz`` omega_base_in_base (rad/s); ``ws*`` wheel
#: speeds relative to the base (rad/s); ``hw*`` wheel momentum, base frame (N m s);
#: ``tqx..tqw`` the ACS target quaternion.
TELEMETRY_FLOAT_FIELDS = STORAGE_LAYOUT.float_fields
#: Fields that can be decimated (min / max / mean per bucket): the numbers.
BUCKET_FIELDS = STORAGE_LAYOUT.bucket_fields
#: Every per-frame value a query may ask for (the whitelist; nothing else reaches SQL).
TELEMETRY_FIELDS = STORAGE_LAYOUT.fields


def stored_layout(n_joints: int, n_wheels: int = STORED_WHEELS) -> FrameLayout:
    """The layout of a robot's frames in the archive; ValueError when the table has no
    columns for it (more than :data:`MAX_STORED_JOINTS` joints, not three wheels)."""
    if not 1 <= n_joints <= MAX_STORED_JOINTS:
        raise ValueError(
            f"the archive stores 1..{MAX_STORED_JOINTS} joints, not {n_joints} (a robot of "
            f"more needs columns j{MAX_STORED_JOINTS + 1}.. added by a migration)"
        )
    if n_wheels != STORED_WHEELS:
        raise ValueError(f"the archive stores {STORED_WHEELS} wheel speeds, not {n_wheels}")
    return FrameLayout(n_joints, n_wheels)


class TelemetryFrameRecord(Base):
    """One telemetry frame of a pass: every value of the wire frame in its own column.

    Keys and TimescaleDB. The primary key is ``(pass_id, seq, generation_time_ns)``: a
    hypertable partitioned on ``generation_time_ns`` requires every unique index to contain
    the partitioning column, so ``(pass_id, seq)`` alone cannot be unique there. It still
    deduplicates by ``(pass_id, seq)``: the spacecraft numbers frames without gaps and a
    frame's ``seq`` fixes its ``generation_time_ns`` (a resent frame is the same stored frame,
    timestamp included), so the second copy of a seq always collides with the first and
    ``INSERT ... ON CONFLICT DO NOTHING`` keeps the first (docs/protocol.md). Should an
    onboard restart ever reuse a seq with a different time, both frames are kept rather than
    the new one silently dropped. ``(pass_id, generation_time_ns)`` is indexed for time-range
    queries and decimation. To convert on a TimescaleDB server (nothing here needs it)::

        SELECT create_hypertable('telemetry_frames',
                                 by_range('generation_time_ns', 600000000000),  -- 10 min
                                 migrate_data => true);
    """

    __tablename__ = "telemetry_frames"

    pass_id: Mapped[str] = mapped_column(UUIDString, ForeignKey("passes.id"))
    seq: Mapped[int]
    generation_time_ns: Mapped[int]
    reception_time_ns: Mapped[int]
    j1: Mapped[float]
    j2: Mapped[float]
    j3: Mapped[float]
    j4: Mapped[float]
    j5: Mapped[float]
    j6: Mapped[float]
    t1: Mapped[float]
    t2: Mapped[float]
    t3: Mapped[float]
    t4: Mapped[float]
    t5: Mapped[float]
    t6: Mapped[float]
    qx: Mapped[float]
    qy: Mapped[float]
    qz: Mapped[float]
    qw: Mapped[float]
    wx: Mapped[float]
    wy: Mapped[float]
    wz: Mapped[float]
    ws1: Mapped[float]
    ws2: Mapped[float]
    ws3: Mapped[float]
    hw1: Mapped[float]
    hw2: Mapped[float]
    hw3: Mapped[float]
    acs_mode: Mapped[str] = mapped_column(String(16))
    tqx: Mapped[float]
    tqy: Mapped[float]
    tqz: Mapped[float]
    tqw: Mapped[float]
    acs_feedforward: Mapped[bool] = mapped_column(Boolean)
    buffer_queued: Mapped[int]
    buffer_next_execute_time_ns: Mapped[int | None]
    buffer_last_executed_seq: Mapped[int]
    # Joints 7..MAX_STORED_JOINTS (revision 0004): NULL where the robot has fewer joints.
    j7: Mapped[float | None]
    j8: Mapped[float | None]
    j9: Mapped[float | None]
    j10: Mapped[float | None]
    j11: Mapped[float | None]
    j12: Mapped[float | None]
    t7: Mapped[float | None]
    t8: Mapped[float | None]
    t9: Mapped[float | None]
    t10: Mapped[float | None]
    t11: Mapped[float | None]
    t12: Mapped[float | None]

    __table_args__ = (
        PrimaryKeyConstraint("pass_id", "seq", "generation_time_ns"),
        Index("ix_telemetry_frames_pass_id_generation_time_ns", "pass_id", "generation_time_ns"),
    )


class EventRecord(Base):
    """The audit log: ``actor`` did ``kind`` at ``time_ns`` (ground), ``detail`` says more."""

    __tablename__ = "events"

    id: Mapped[int] = mapped_column(BigIntKey, primary_key=True, autoincrement=True)
    pass_id: Mapped[str | None] = mapped_column(UUIDString, ForeignKey("passes.id"))
    time_ns: Mapped[int]
    kind: Mapped[str] = mapped_column(String(64))
    actor: Mapped[str] = mapped_column(String(128))
    detail: Mapped[dict[str, Any]]

    __table_args__ = (
        Index("ix_events_time_ns", "time_ns"),
        Index("ix_events_pass_id_time_ns", "pass_id", "time_ns"),
        Index("ix_events_kind_time_ns", "kind", "time_ns"),
    )


class AnalysisRecord(Base):
    """A post-pass analysis of one ``kind``; the newest of a kind is the current one."""

    __tablename__ = "analysis_results"

    id: Mapped[int] = mapped_column(BigIntKey, primary_key=True, autoincrement=True)
    pass_id: Mapped[str] = mapped_column(UUIDString, ForeignKey("passes.id"))
    kind: Mapped[str] = mapped_column(String(64))
    created_at_ns: Mapped[int]
    result: Mapped[dict[str, Any]]

    __table_args__ = (
        Index("ix_analysis_results_pass_id_kind_created_at_ns", "pass_id", "kind", "created_at_ns"),
    )


class AlarmRecord(Base):
    """An alarm: a quantity's channel in a band of its limits (``source`` ``limit``), or the
    vehicle's safing (``vehicle``), for one pass (``pass_id`` NULL: no pass was running).

    ``severity`` is the worst band reached, ``current_severity`` the band now (NULL: back
    within limits, ``state`` ``cleared``). ``limit_value`` is the threshold of the worst
    band (the ``limit`` of the alarm's JSON). ``timeline`` lists every change of band:
    ``[{"severity": str | None, "generation_time_ns", "time_ns", "frame_seq", "value"}]``
    (``generation_time_ns`` onboard, ``time_ns`` ground). ``raised_generation_time_ns`` and
    ``cleared_generation_time_ns`` are onboard times (the frame's); every other ``*_ns``
    is ground time. docs/alarms.md.
    """

    __tablename__ = "alarms"

    id: Mapped[str] = mapped_column(UUIDString, primary_key=True)
    pass_id: Mapped[str | None] = mapped_column(UUIDString, ForeignKey("passes.id"))
    quantity: Mapped[str] = mapped_column(String(64))
    channel: Mapped[str] = mapped_column(String(32))
    label: Mapped[str] = mapped_column(String(128))
    unit: Mapped[str] = mapped_column(String(16))
    direction: Mapped[str] = mapped_column(String(8))
    source: Mapped[str] = mapped_column(String(16))
    severity: Mapped[str] = mapped_column(String(16))
    current_severity: Mapped[str | None] = mapped_column(String(16))
    state: Mapped[str] = mapped_column(String(16))
    acknowledged: Mapped[bool] = mapped_column(Boolean)
    acknowledged_by: Mapped[str | None] = mapped_column(String(128))
    acknowledged_time_ns: Mapped[int | None]
    comment: Mapped[str | None] = mapped_column(Text)
    limit_value: Mapped[float | None]
    trigger_value: Mapped[float | None]
    worst_value: Mapped[float | None]
    last_value: Mapped[float | None]
    #: Frames (or reports) in a band since the alarm was raised.
    count: Mapped[int]
    raised_frame_seq: Mapped[int | None]
    raised_generation_time_ns: Mapped[int | None]
    raised_time_ns: Mapped[int]
    updated_time_ns: Mapped[int]
    cleared_generation_time_ns: Mapped[int | None]
    cleared_time_ns: Mapped[int | None]
    timeline: Mapped[list[dict[str, Any]]] = mapped_column(JSONDocument)
    detail: Mapped[str | None] = mapped_column(Text)

    __table_args__ = (
        CheckConstraint(_one_of("severity", ALARM_SEVERITIES), name="severity"),
        CheckConstraint(
            f"current_severity IS NULL OR {_one_of('current_severity', ALARM_SEVERITIES)}",
            name="current_severity",
        ),
        CheckConstraint(_one_of("source", ALARM_SOURCES), name="source"),
        CheckConstraint(_one_of("state", ALARM_STATES), name="state"),
        CheckConstraint(_one_of("direction", ALARM_DIRECTIONS), name="direction"),
        Index("ix_alarms_raised_time_ns", "raised_time_ns"),
        Index("ix_alarms_pass_id_raised_time_ns", "pass_id", "raised_time_ns"),
        # the active ones: triggered, or cleared and not yet acknowledged
        Index("ix_alarms_acknowledged_state", "acknowledged", "state"),
    )


class GroundLease(Base):
    """The command authority over a vehicle (server/storage/lease.py): the ground that holds
    it (``holder``, a process's own name), its **fencing token** (raised by one at every
    acquisition, never reused) and its expiry. Times are the **database's** clock, seconds
    since the Unix epoch (a float), so grounds on machines whose clocks disagree still agree
    on who holds it. One row per lease name; a holder of ``""`` holds nothing."""

    __tablename__ = "ground_leases"

    name: Mapped[str] = mapped_column(String(64), primary_key=True)
    holder: Mapped[str] = mapped_column(String(128))
    token: Mapped[int] = mapped_column(BigInteger)
    acquired_s: Mapped[float] = mapped_column(Double)
    renewed_s: Mapped[float] = mapped_column(Double)
    expires_s: Mapped[float] = mapped_column(Double)
