"""The pass's commands: queued in bulk, each stage recorded with its time, cancelled in
bulk, listed by time tag (docs/protocol.md for the stages, :mod:`server.storage.models` for
which clock each time is on). Like every repository function they run inside the caller's
transaction and never commit; :mod:`server.storage.repository` re-exports them.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence
from typing import Any, cast

from sqlalchemy import ColumnElement, Table, bindparam, select, update
from sqlalchemy.orm import Session
from sqlalchemy.orm.attributes import set_committed_value

from server.storage._common import (
    canonical_id,
    check_one_of,
    check_page,
    flush,
    insert_rows,
    require_pass,
    within,
)
from server.storage.errors import NotFound
from server.storage.models import COMMAND_KINDS, COMMAND_STAGES, CommandRecord
from server.storage.stages import OPEN_STAGES
from telemetry.wire import AcsCommandMsg, JointCommandMsg

__all__ = [
    "add_commands",
    "cancel_commands",
    "get_command",
    "list_commands",
    "load_commands",
    "update_command_stage",
    "update_commands",
]

#: Fields of a wire command that have their own columns; the rest is the payload.
_COMMAND_COLUMNS = {"v", "type", "kind", "seq", "execute_time_ns"}


def add_commands(
    *,
    session: Session,
    pass_id: str,
    commands: Sequence[JointCommandMsg | AcsCommandMsg],
    queued_at_ns: int,
) -> int:
    """Queue ``commands`` for the pass in one bulk insert; the number stored.

    A ``seq`` the pass already has raises :class:`Conflict` (and nothing of the batch is
    kept once the session rolls back).
    """
    key = require_pass(session, pass_id)
    rows = [
        {
            "pass_id": key,
            "seq": command.seq,
            "kind": command.kind,
            "execute_time_ns": command.execute_time_ns,
            "payload": command.model_dump(mode="json", exclude=_COMMAND_COLUMNS),
            "stage": "queued",
            "queued_at_ns": queued_at_ns,
        }
        for command in commands
    ]
    return insert_rows(session, CommandRecord, rows, what=f"commands of pass {key}")


def get_command(*, session: Session, pass_id: str, seq: int) -> CommandRecord:
    record = session.get(CommandRecord, (canonical_id(pass_id, what="pass"), seq))
    if record is None:
        raise NotFound(f"command {seq} of pass {pass_id!r} not found")
    return record


def load_commands(
    *, session: Session, pass_id: str, seqs: Collection[int]
) -> dict[int, CommandRecord]:
    """These commands of the pass (those stored), by seq, as the transaction holds them, in
    one statement per thousand seqs (objects already in the session are refreshed)."""
    key = canonical_id(pass_id, what="pass")
    wanted = sorted(set(seqs))
    session.flush()  # what the session holds unwritten goes first: the rows read are current
    out: dict[int, CommandRecord] = {}
    for lo in range(0, len(wanted), 1000):
        rows = session.scalars(
            select(CommandRecord)
            .where(CommandRecord.pass_id == key, CommandRecord.seq.in_(wanted[lo : lo + 1000]))
            .execution_options(populate_existing=True)
        )
        out.update((row.seq, row) for row in rows)
    return out


def update_commands(
    *, session: Session, records: Mapping[int, CommandRecord], values: Mapping[int, dict[str, Any]]
) -> None:
    """Set each command's columns to ``values[seq]`` (column -> value; ``records`` from
    :func:`load_commands`), in one statement per set of columns however many commands (an
    executemany): the command stages' writes of a whole group commit. The session's objects
    are set to match (nothing of them is flushed again)."""
    table = cast(Table, CommandRecord.__table__)
    by_columns: dict[tuple[str, ...], list[dict[str, Any]]] = {}
    for seq, changed in values.items():
        if not changed:
            continue
        record = records[seq]
        for column, value in changed.items():
            check_one_of(column, _STAGE_COLUMNS, what="command column")
            set_committed_value(record, column, value)
        params = {"k_pass": record.pass_id, "k_seq": seq, **changed}
        by_columns.setdefault(tuple(sorted(changed)), []).append(params)
    for rows in by_columns.values():
        session.execute(
            update(table).where(
                table.c.pass_id == bindparam("k_pass", type_=table.c.pass_id.type),
                table.c.seq == bindparam("k_seq"),
            ),
            rows,
        )


#: The columns :func:`update_commands` sets: a stage, its time, a refusal's reason, the count
#: of transmissions.
_STAGE_COLUMNS = (
    "stage",
    "reject_reason",
    "transmissions",
    *(f"{stage}_at_ns" for stage in COMMAND_STAGES),
)


def update_command_stage(
    *,
    session: Session,
    pass_id: str,
    seq: int,
    stage: str,
    time_ns: int,
    reject_reason: str | None = None,
) -> CommandRecord:
    """Set the command's stage and record ``time_ns`` as ``<stage>_at_ns``.

    ``time_ns`` is on the clock the models name for that stage (onboard for ``received``,
    ``executed``, ``rejected``). The stage is set as given, even backwards: acknowledgements
    may arrive out of order, and which one wins is the service's rule.
    """
    check_one_of(stage, COMMAND_STAGES, what="command stage")
    record = get_command(session=session, pass_id=pass_id, seq=seq)
    record.stage = stage
    setattr(record, f"{stage}_at_ns", time_ns)
    if reject_reason is not None:
        record.reject_reason = reject_reason
    flush(session, f"command {seq} of pass {pass_id}")
    return record


def cancel_commands(*, session: Session, pass_id: str, seqs: Collection[int], time_ns: int) -> int:
    """Set these commands of the pass ``cancelled`` at ``time_ns`` (ground clock), those not
    already in a final stage, in one statement per thousand seqs; how many changed."""
    key = canonical_id(pass_id, what="pass")
    wanted = sorted(set(seqs))
    changed = 0
    for lo in range(0, len(wanted), 1000):
        result = session.execute(
            update(CommandRecord)
            .where(
                CommandRecord.pass_id == key,
                CommandRecord.seq.in_(wanted[lo : lo + 1000]),
                CommandRecord.stage.in_(OPEN_STAGES),
            )
            .values(stage="cancelled", cancelled_at_ns=time_ns)
            # objects of these rows already in the session are updated by evaluating the
            # criteria in Python: an abort of a long pass does not fetch thousands back
            .execution_options(synchronize_session="evaluate")
        )
        changed += int(result.rowcount or 0)  # type: ignore[attr-defined]
    return changed


def list_commands(
    *,
    session: Session,
    pass_id: str,
    stages: Collection[str] | None = None,
    execute_from_ns: int | None = None,
    execute_to_ns: int | None = None,
    limit: int | None = None,
    kinds: Collection[str] | None = None,
) -> list[CommandRecord]:
    """The pass's commands by time tag (then seq): only ``stages`` and ``kinds`` if given,
    and only tags in ``[execute_from_ns, execute_to_ns)`` for the bounds given."""
    where: list[ColumnElement[bool]] = [CommandRecord.pass_id == canonical_id(pass_id, what="pass")]
    if stages is not None:
        for stage in stages:
            check_one_of(stage, COMMAND_STAGES, what="command stage")
        where.append(CommandRecord.stage.in_(list(stages)))
    if kinds is not None:
        for kind in kinds:
            check_one_of(kind, COMMAND_KINDS, what="command kind")
        where.append(CommandRecord.kind.in_(list(kinds)))
    where += within(CommandRecord.execute_time_ns, execute_from_ns, execute_to_ns)
    query = (
        select(CommandRecord)
        .where(*where)
        .order_by(CommandRecord.execute_time_ns, CommandRecord.seq)
    )
    if limit is not None:
        check_page(0, limit)
        query = query.limit(limit)
    return list(session.scalars(query))
