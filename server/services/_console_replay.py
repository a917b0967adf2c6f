"""Console streams in the database: the telemetry rows (a pass's robot's
:class:`telemetry.layout.FrameLayout`), and finding a stream's
messages again by the keys the hub indexed them under (:mod:`server.services.console`).

A telemetry message is the frames of one archive batch of one pass: its key is
``(reception_time_ns, lowest generation_time_ns, highest, frame count)``; the frames come
back as the rows of that pass with that ``reception_time_ns`` (one batch, one reception
time). An event message's key is ``(time_ns, kind, pass_id)``; it comes back as the event
row with those values (several with the same key are matched in id order). Either replay
returns None unless every message is found whole: the caller then tells the client to
resync rather than replay part of a stream.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Collection
from dataclasses import dataclass
from typing import Any

from sqlalchemy.orm import Session, sessionmaker

from server.services.console_messages import ConsoleEvent
from server.storage import repository as repo
from telemetry.layout import DEFAULT_LAYOUT, FrameLayout
from telemetry.wire import TelemetryFrame

__all__ = ["COLUMNS", "Row", "TelemetryRows", "replay_events", "replay_frames", "telemetry_rows"]

#: One ETS-VII frame as the console sends it; another robot's is its layout's
#: :attr:`~telemetry.layout.FrameLayout.columns` (the layout of ``repository.telemetry_range``
#: rows asked for every field of the pass, so live frames and frames read back are alike).
COLUMNS = DEFAULT_LAYOUT.columns
Row = tuple[Any, ...]
assert COLUMNS[-1] == "reception_time_ns"

#: Event rows read per query.
PAGE = 5000
Entry = tuple[int, Any]  # (seq, key)
Found = tuple[int, Any, Any]  # (seq, key, payload)


@dataclass(frozen=True)
class TelemetryRows:
    """A telemetry message's frames: rows of ``columns`` (one robot's layout)."""

    columns: tuple[str, ...]
    rows: list[Row]


def telemetry_rows(frames: list[TelemetryFrame], reception_time_ns: int) -> TelemetryRows:
    """Frames (of one robot: the first frame's layout) as rows of that layout's columns,
    in generation-time order (as read back)."""
    layout = FrameLayout.of_frame(frames[0]) if frames else DEFAULT_LAYOUT
    rows = layout.rows(frames, reception_time_ns)
    rows.sort(key=lambda row: (row[1], row[0]))
    return TelemetryRows(layout.columns, rows)


def replay_frames(
    sessions: sessionmaker[Session], pass_id: str, entries: list[Entry]
) -> list[Found] | None:
    """The telemetry messages ``entries`` of the pass, or None if one is not whole."""
    by_reception: dict[int, int] = {}
    for seq, (reception_ns, _, _, _) in entries:
        if reception_ns in by_reception:
            return None  # two batches at one instant: they cannot be told apart
        by_reception[reception_ns] = seq
    t0_ns = min(key[1] for _, key in entries)
    t1_ns = max(key[2] for _, key in entries) + 1
    with sessions() as session:
        layout = repo.get_pass_layout(session=session, pass_id=pass_id)
        found = repo.telemetry_range(
            session=session, pass_id=pass_id, t0_ns=t0_ns, t1_ns=t1_ns, fields=layout.fields
        )
    rows: dict[int, list[Row]] = {seq: [] for seq, _ in entries}
    for row in found:
        owner = by_reception.get(row[-1])
        if owner is not None:
            rows[owner].append(tuple(row))
    out = []
    for seq, key in entries:
        if len(rows[seq]) != key[3]:
            return None
        out.append((seq, key, TelemetryRows(layout.columns, rows[seq])))
    return out


def replay_events(
    sessions: sessionmaker[Session], kinds: Collection[str] | None, entries: list[Entry]
) -> list[Found] | None:
    """The event messages ``entries``, or None if one is not found."""
    waiting: dict[Any, deque[int]] = {}
    for seq, key in entries:
        waiting.setdefault(key, deque()).append(seq)
    t0_ns = min(key[0] for _, key in entries)
    t1_ns = max(key[0] for _, key in entries) + 1
    found: dict[int, Found] = {}
    offset = 0
    with sessions() as session:
        while True:
            page = repo.list_events(
                session=session,
                kinds=kinds,
                t0_ns=t0_ns,
                t1_ns=t1_ns,
                offset=offset,
                limit=PAGE,
            )
            for record in page.items:
                key = (record.time_ns, record.kind, record.pass_id)
                seqs = waiting.get(key)
                if seqs:
                    event = ConsoleEvent(
                        kind=record.kind,
                        actor=record.actor,
                        detail=record.detail,
                        pass_id=record.pass_id,
                        time_ns=record.time_ns,
                        id=record.id,
                    )
                    seq = seqs.popleft()
                    found[seq] = (seq, key, event)
            offset += len(page.items)
            if not page.items or offset >= page.count:
                break
    if len(found) != len(entries):
        return None
    return [found[seq] for seq, _ in entries]
