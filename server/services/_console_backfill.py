"""After a takeover, the frames the ground gone had archived but not yet published
(docs/console.md "Across grounds").

A ground publishes a pass's frames to JetStream once they are committed, from a queue; killed
between the two, it leaves frames in the archive that no console sees live. The ground that
takes the command lease over reads, for each pass whose telemetry window is open, the last
telemetry message JetStream holds for it (one subject: ``get_last_msg``), and publishes the
archive's frames after that message's last frame, in order, before its own link brings new
ones. Every console on any ground then gets them through the stream, numbered as the rest.

Retransmitted frames (older seqs stored late) that the ground gone archived and did not
publish are not looked for: the tail after the stream's last frame is.
"""

from __future__ import annotations

import asyncio
import json
import logging
from typing import TYPE_CHECKING

from sqlalchemy import or_, select
from sqlalchemy.orm import Session, sessionmaker

from server.services._console_limits import canonical_pass
from server.storage import repository as repo
from server.storage.models import PassRecord

if TYPE_CHECKING:
    from server.services._console_jetstream import AcrossGrounds

__all__ = ["backfill"]

log = logging.getLogger("hikoboshi.ground.console")

#: rows a backfilled telemetry message carries (the live ones carry a link message's frames)
BATCH_ROWS = 200
#: frames read back for one pass at most (a ground gone before publishing anything of a
#: long pass: the rest is in the archive, where a console's replay finds it)
LIMIT_ROWS = 40_000
_END_NS = 2**63 - 1


_UNFINISHED = ("aos", "running", "los")


def _open_passes(session: Session) -> list[tuple[str, bool]]:
    """The passes whose frames may still be arriving, and whether each is unfinished (else
    its window is open)."""
    open_window = PassRecord.telemetry_start_ns.is_not(None) & PassRecord.telemetry_end_ns.is_(None)
    query = select(PassRecord.id, PassRecord.state).where(
        or_(PassRecord.state.in_(_UNFINISHED), open_window)
    )
    return [(str(pass_id), state in _UNFINISHED) for pass_id, state in session.execute(query)]


def _after(last: bytes | None) -> tuple[int, int]:
    """``(seq, generation_time_ns)`` of the last frame of a telemetry message ((-1, 0): none)."""
    if last is None:
        return -1, 0
    doc = json.loads(last)
    columns = list(doc["columns"])
    i_seq, i_gen = columns.index("seq"), columns.index("generation_time_ns")
    row = max(doc["rows"], key=lambda r: (r[i_seq], r[i_gen]))
    return int(row[i_seq]), int(row[i_gen])


def _unpublished(
    sessions: sessionmaker[Session], pass_id: str, after_seq: int, after_ns: int
) -> tuple[tuple[str, ...], list[tuple[object, ...]]]:
    with sessions() as session:
        layout = repo.get_pass_layout(session=session, pass_id=pass_id)
        found = repo.telemetry_range(
            session=session,
            pass_id=pass_id,
            t0_ns=after_ns,
            t1_ns=_END_NS,
            fields=layout.fields,
            limit=LIMIT_ROWS,
        )
    return layout.columns, [tuple(row) for row in found if row[0] > after_seq]


async def backfill(across: AcrossGrounds, sessions: sessionmaker[Session]) -> int:
    """Publish the open passes' archived frames that JetStream does not hold; how many."""
    bus = across.bus

    def passes() -> list[tuple[str, bool]]:
        with sessions() as session:
            return _open_passes(session)

    total = 0
    for pass_id, unfinished in await asyncio.to_thread(passes):
        name = canonical_pass(pass_id) or pass_id
        last = await bus.last_on(bus.subject("telemetry", name))
        if last is None and not unfinished:
            continue  # an ended pass the stream no longer holds (or never did): not live
        after_seq, after_ns = _after(last)
        columns, rows = await asyncio.to_thread(
            _unpublished, sessions, pass_id, after_seq, after_ns
        )
        for i in range(0, len(rows), BATCH_ROWS):
            doc = {"pass_id": name, "columns": list(columns), "rows": rows[i : i + BATCH_ROWS]}
            bus.publish(bus.subject("telemetry", name), json.dumps(doc).encode())
        if rows:
            log.warning(
                "pass %s: %d frames archived by the ground gone but not published, "
                "published now (from seq %d)",
                pass_id,
                len(rows),
                rows[0][0],
                extra={"fields": {"event": "backfill", "frames": len(rows)}},
            )
        total += len(rows)
    return total
