"""Telemetry of a pass, raw or decimated, and the audit log.

Field names are checked here against the storage's whitelists, then against the pass's
robot's layout (a 6-joint pass has no ``j7``), so that an unknown one is an invalid request naming
it (the storage would refuse it too, as an ``InvalidArgument``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from pydantic import TypeAdapter
from sqlalchemy.orm import Session

from server.schemas import MAX_NS, iso_from_ns
from server.schemas.telemetry import (
    EventPublic,
    EventsPublic,
    QuantityAcrossPublic,
    QuantityBucketPublic,
    QuantityPassPublic,
    TelemetryBucketPublic,
    TelemetryPublic,
    TelemetryRowPublic,
)
from server.services.errors import InvalidRequestError
from server.services.passes import check_range
from server.storage import repository as repo
from server.storage._telemetry import MAX_BUCKETS
from server.storage.models import BUCKET_FIELDS, TELEMETRY_FIELDS

__all__ = [
    "MAX_ACROSS_PASSES",
    "MAX_BUCKETS",
    "across_passes",
    "list_events",
    "telemetry",
    "telemetry_json",
]

#: The most passes one cross-pass query compares.
MAX_ACROSS_PASSES = 20

_WHAT = {False: "telemetry", True: "numeric (bucketable)"}


def parse_fields(text: str | None, *, allowed: tuple[str, ...], what: str) -> list[str]:
    """``"j1,j2"`` -> ``["j1", "j2"]``, each in ``allowed``; every allowed field if none."""
    if text is None or not text.strip():
        return list(allowed)
    names = [name.strip() for name in text.split(",") if name.strip()]
    for name in names:
        if name not in allowed:
            shown = name if len(name) <= 40 else name[:37] + "..."
            raise InvalidRequestError(
                "unknown_field",
                f"telemetry field {shown!r} is not one of the {what} fields {list(allowed)}",
                {"field": shown},
            )
    if len(set(names)) != len(names):
        raise InvalidRequestError("repeated_field", f"telemetry fields {names} repeat a name")
    return names


def telemetry(
    *,
    session: Session,
    pass_id: str,
    t0_ns: int,
    t1_ns: int,
    fields: str | None,
    buckets: int | None,
    limit: int,
) -> TelemetryPublic:
    """Frames with ``t0_ns <= generation_time_ns < t1_ns``: the first ``limit`` raw rows, or
    ``buckets`` equal spans with min / max / mean per field (empty spans left out; an open
    end, 0 or :data:`MAX_NS`, at the stored frames' first or last)."""
    if t1_ns <= t0_ns:
        raise InvalidRequestError("empty_range", f"time range [{t0_ns}, {t1_ns}) ns is empty")
    allowed = BUCKET_FIELDS if buckets is not None else TELEMETRY_FIELDS
    parse_fields(fields, allowed=allowed, what=_WHAT[buckets is not None])
    # The pass's robot's values only (ETS-VII: j1..j6, t1..t6): every one of them if none
    # were asked for.
    layout = repo.get_pass_layout(session=session, pass_id=pass_id)
    if buckets is None:
        names = parse_fields(fields, allowed=layout.fields, what=f"{layout} telemetry")
        # one row past the page: whether there is more, without reading the rest
        rows = repo.telemetry_range(
            session=session,
            pass_id=pass_id,
            t0_ns=t0_ns,
            t1_ns=t1_ns,
            fields=names,
            limit=limit + 1,
        )
        kept = [tuple(row) for row in rows[:limit]]
        return TelemetryPublic(
            **_read(session, pass_id, names, t0_ns, t1_ns),
            mode="raw",
            count=len(kept),
            truncated=len(rows) > limit,
            rows=[
                TelemetryRowPublic(
                    seq=row[0],
                    generation_time_ns=row[1],
                    generation_time=iso_from_ns(row[1]),
                    values={name: row[2 + i] for i, name in enumerate(names)},
                )
                for row in kept
            ],
        )
    names = parse_fields(
        fields, allowed=layout.bucket_fields, what=f"{layout} numeric (bucketable)"
    )
    # An open end (from 0, until MAX_NS: the defaults) is the stored frames' end: ten spans
    # of [0, 2**63) were one of 29 years, dated 1999-03-25.
    extent = repo.telemetry_extent(session=session, pass_id=pass_id)
    if extent is not None:
        start = extent.first_ns if t0_ns == 0 else t0_ns
        end = extent.last_ns + 1 if t1_ns == MAX_NS else t1_ns
        if start < end:  # else nothing is stored in the range asked: no span either way
            t0_ns, t1_ns = start, end
    result = repo.telemetry_buckets(
        session=session, pass_id=pass_id, t0_ns=t0_ns, t1_ns=t1_ns, fields=names, buckets=buckets
    )
    return TelemetryPublic(
        **_read(session, pass_id, names, t0_ns, t1_ns),
        mode="buckets",
        count=len(result),
        width_ns=-(-(t1_ns - t0_ns) // buckets),
        buckets=[
            TelemetryBucketPublic(
                t_start_ns=b.t_start_ns,
                t_start=iso_from_ns(b.t_start_ns),
                count=b.count,
                min=b.min,
                max=b.max,
                mean=b.mean,
            )
            for b in result
        ],
    )


def _read(
    session: Session, pass_id: str, names: list[str], t0_ns: int, t1_ns: int
) -> dict[str, Any]:
    """A telemetry answer's header, raw or in buckets: what was read of which pass (its
    stored id), the ``names`` over ``[t0_ns, t1_ns)``."""
    record = repo.get_pass(session=session, pass_id=pass_id)
    return {"pass_id": record.id, "fields": names, "t0_ns": t0_ns, "t1_ns": t1_ns}


def across_passes(
    *, session: Session, field: str, pass_ids: Sequence[str], buckets: int
) -> QuantityAcrossPublic:
    """One numeric telemetry field of each pass in ``pass_ids`` (in that order), each
    decimated into ``buckets`` equal spans of its own stored duration, on a time axis from
    its first frame, with its whole-pass min / max / mean: the same quantity compared across
    passes (a pass with no frames is listed with ``count`` 0)."""
    if not pass_ids:
        raise InvalidRequestError("no_passes", "name at least one pass (pass_id=...)")
    if len(pass_ids) > MAX_ACROSS_PASSES:
        raise InvalidRequestError(
            "too_many_passes",
            f"{len(pass_ids)} passes: compare at most {MAX_ACROSS_PASSES} at once",
        )
    if len(set(pass_ids)) != len(pass_ids):
        raise InvalidRequestError("repeated_pass", f"passes {list(pass_ids)} repeat an id")
    if not 1 <= buckets <= MAX_BUCKETS:
        raise InvalidRequestError("bad_buckets", f"{buckets} buckets is outside 1..{MAX_BUCKETS}")
    names = parse_fields(field, allowed=BUCKET_FIELDS, what=_WHAT[True])
    if len(names) != 1:
        raise InvalidRequestError("one_field", f"compare one field at a time, not {names}")
    (name,) = names
    unit = ""
    out: list[QuantityPassPublic] = []
    for pass_id in pass_ids:
        record = repo.get_pass(session=session, pass_id=pass_id)
        layout = repo.get_pass_layout(session=session, pass_id=pass_id)
        if name not in layout.bucket_fields:
            raise InvalidRequestError(
                "unknown_field",
                f"pass {record.id} ({layout}) has no telemetry field {name!r}",
                {"field": name, "pass_id": record.id},
            )
        unit = layout.units[name]
        extent = repo.telemetry_extent(session=session, pass_id=record.id)
        if extent is None:
            out.append(
                QuantityPassPublic(pass_id=record.id, name=record.name, state=record.state, count=0)
            )
            continue
        t0, t1 = extent.first_ns, extent.last_ns + 1
        width = -(-(t1 - t0) // buckets)
        spans = repo.telemetry_buckets(
            session=session, pass_id=record.id, t0_ns=t0, t1_ns=t1, fields=[name], buckets=buckets
        )
        whole = repo.telemetry_buckets(
            session=session, pass_id=record.id, t0_ns=t0, t1_ns=t1, fields=[name], buckets=1
        )[0]
        out.append(
            QuantityPassPublic(
                pass_id=record.id,
                name=record.name,
                state=record.state,
                count=extent.count,
                first_ns=t0,
                first=iso_from_ns(t0),
                duration_s=(extent.last_ns - t0) / 1e9,
                width_s=width / 1e9,
                min=whole.min[name],
                max=whole.max[name],
                mean=whole.mean[name],
                buckets=[
                    QuantityBucketPublic(
                        t_s=(b.t_start_ns - t0) / 1e9,
                        count=b.count,
                        min=b.min[name],
                        max=b.max[name],
                        mean=b.mean[name],
                    )
                    for b in spans
                ],
            )
        )
    return QuantityAcrossPublic(field=name, unit=unit, buckets=buckets, passes=out)


def telemetry_json(**kwargs: Any) -> bytes:
    """:func:`telemetry` as the JSON document the API answers with (``kwargs`` as
    :func:`telemetry`'s). What a worker process hands back for a page of raw rows: a
    5,000-row page is 4 MB of JSON, and its model, unpickled and encoded in the server,
    held the interpreter for half a second per read (the encoding on the event loop, where
    the telemetry link and the uplink run); bytes cost the server a copy."""
    return _TELEMETRY_JSON.dump_json(telemetry(**kwargs))


_TELEMETRY_JSON = TypeAdapter(TelemetryPublic)


def list_events(
    *,
    session: Session,
    pass_id: str | None,
    offset: int,
    limit: int,
    kinds: Sequence[str] | None = None,
    actors: Sequence[str] | None = None,
    t0_ns: int | None = None,
    t1_ns: int | None = None,
) -> EventsPublic:
    """The audit log in time order: of one pass, of ``kinds``, by ``actors`` and stamped in
    ``[t0_ns, t1_ns)``, where given (``NotFound`` for an unknown pass, ``empty_range`` for
    an empty range)."""
    check_range(t0_ns, t1_ns)
    if pass_id is not None:
        pass_id = repo.get_pass(session=session, pass_id=pass_id).id
    page = repo.list_events(
        session=session,
        pass_id=pass_id,
        kinds=kinds,
        actors=actors,
        t0_ns=t0_ns,
        t1_ns=t1_ns,
        offset=offset,
        limit=limit,
    )
    return EventsPublic(
        data=[
            EventPublic(
                id=e.id,
                pass_id=e.pass_id,
                time=iso_from_ns(e.time_ns),
                time_ns=e.time_ns,
                kind=e.kind,
                actor=e.actor,
                detail=e.detail,
            )
            for e in page.items
        ],
        count=page.count,
    )
