"""``/api/passes/{id}/telemetry`` (and its whole-pass exports ``telemetry.csv`` and
``telemetry.parquet``) and ``/api/events``: the archive, read-only (viewer).

Raw telemetry (up to :data:`MAX_ROWS` rows of a range that may span a whole pass) is read
in a worker process (:mod:`server.services.workers`) on its own database connection; a
full pool answers 503 ``busy`` with ``Retry-After``, past ``read_deadline_s`` 504. Buckets
(at most ``MAX_BUCKETS`` aggregates computed by the database) stay in the server. The exports
read the pass in pages on worker threads (server/services/exports.py); like every heavy
read they count against the caller's ``heavy_reads_per_token`` (server/api/lanes.py)."""

from __future__ import annotations

from collections.abc import AsyncIterator, Iterator
from typing import Annotated

from fastapi import APIRouter, Query, Request
from fastapi.responses import Response, StreamingResponse
from pydantic import StringConstraints
from sqlalchemy.orm import Session, sessionmaker
from starlette.concurrency import run_in_threadpool

from server.api.deps import (
    IdPath,
    ReadSessionsDep,
    SessionDep,
    SettingsDep,
    ViewerDep,
    WorkersDep,
)
from server.api.openapi import file_content
from server.schemas import ERROR_RESPONSES, MAX_NS, EventKind, SafeLine
from server.schemas.telemetry import EventsPublic, QuantityAcrossPublic, TelemetryPublic
from server.services import exports
from server.services import telemetry as service
from server.services.jobs import read_session_job

__all__ = ["router"]

router = APIRouter(prefix="/api", responses=ERROR_RESPONSES)

#: The most raw rows one request returns.
MAX_ROWS = 10_000


@router.get("/passes/{pass_id}/telemetry", response_model=TelemetryPublic, tags=["telemetry"])
async def get_telemetry(
    pass_id: IdPath,
    http: Request,
    session: SessionDep,
    settings: SettingsDep,
    _: ViewerDep,
    workers: WorkersDep,
    t0: Annotated[int, Query(ge=0, le=MAX_NS, description="from, ns (onboard clock)")] = 0,
    t1: Annotated[int, Query(ge=0, le=MAX_NS, description="until, ns, excluded")] = MAX_NS,
    fields: Annotated[SafeLine | None, Query(max_length=2000, description="j1,j2,...")] = None,
    buckets: Annotated[int | None, Query(ge=1, le=service.MAX_BUCKETS)] = None,
    limit: Annotated[int, Query(ge=1, le=MAX_ROWS, description="raw rows at most")] = 5000,
) -> TelemetryPublic | Response:
    """Frames generated in ``[t0, t1)``: raw rows (at most ``limit``), or with ``buckets``
    that many equal spans with min / max / mean per field."""
    if buckets is not None:
        return await run_in_threadpool(
            service.telemetry,
            session=session,
            pass_id=pass_id,
            t0_ns=t0,
            t1_ns=t1,
            fields=fields,
            buckets=buckets,
            limit=limit,
        )
    # encoded in the worker process: the server only sends the bytes (service.telemetry_json)
    body = await workers.run(
        read_session_job,
        settings.resolved_database_url(),
        service.telemetry_json,
        pass_id=pass_id,
        t0_ns=t0,
        t1_ns=t1,
        fields=fields,
        buckets=None,
        limit=limit,
        deadline_s=settings.read_deadline_s,
        what=f"telemetry of pass {pass_id}",
        client=http,
    )
    return Response(body, media_type="application/json")


@router.get("/telemetry/across", response_model=QuantityAcrossPublic, tags=["telemetry"])
async def quantity_across_passes(
    session: SessionDep,
    _: ViewerDep,
    field: Annotated[
        SafeLine, Query(max_length=40, description="one numeric field, e.g. hw1 or qz")
    ],
    pass_id: Annotated[
        list[Annotated[SafeLine, StringConstraints(min_length=1, max_length=64)]],
        Query(description=f"repeatable, at most {service.MAX_ACROSS_PASSES}"),
    ],
    buckets: Annotated[int, Query(ge=1, le=service.MAX_BUCKETS)] = 200,
) -> QuantityAcrossPublic:
    """One quantity across several passes: each pass's stored frames of ``field``
    decimated into ``buckets`` equal spans from its own first frame (min / max / mean, in
    the database), with its whole-pass min / max / mean, in the order the passes are named."""
    return await run_in_threadpool(
        service.across_passes, session=session, field=field, pass_ids=pass_id, buckets=buckets
    )


@router.get("/events", response_model=EventsPublic, tags=["events"])
def list_events(
    session: SessionDep,
    _: ViewerDep,
    pass_id: Annotated[SafeLine | None, Query(max_length=64)] = None,
    offset: Annotated[int, Query(ge=0, le=1_000_000_000)] = 0,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
    kind: Annotated[list[EventKind] | None, Query(description="e.g. pass_state")] = None,
    actor: Annotated[
        list[Annotated[SafeLine, StringConstraints(min_length=1, max_length=128)]] | None,
        Query(description="who: a token's name, link, runner, ..."),
    ] = None,
    t0: Annotated[int | None, Query(ge=0, le=MAX_NS, description="from, ns (UTC)")] = None,
    t1: Annotated[int | None, Query(ge=0, le=MAX_NS, description="until, ns, excluded")] = None,
) -> EventsPublic:
    """The audit log in time order: of one pass, of ``kind`` and by ``actor`` (each
    repeatable), stamped in ``[t0, t1)``, where given (422 ``empty_range`` when
    ``t1 <= t0``)."""
    return service.list_events(
        session=session,
        pass_id=pass_id,
        kinds=kind,
        actors=actor,
        t0_ns=t0,
        t1_ns=t1,
        offset=offset,
        limit=limit,
    )


def _attachment(export: exports.TelemetryExport, suffix: str) -> dict[str, str]:
    return {
        "Content-Disposition": f'attachment; filename="pass-{export.pass_id}-telemetry.{suffix}"'
    }


_EXPORT_CONTENT = {
    "csv": file_content("text/csv", text=True),
    "parquet": file_content("application/vnd.apache.parquet"),
}


@router.get(
    "/passes/{pass_id}/telemetry.csv",
    tags=["telemetry"],
    response_class=Response,
    responses={200: {"content": _EXPORT_CONTENT["csv"], "description": "Every frame, as CSV"}},
)
async def export_telemetry_csv(
    pass_id: IdPath, _: ViewerDep, sessions: ReadSessionsDep
) -> Response:
    """Every stored frame of the pass in time order, as CSV: the frame layout's columns,
    each header with its unit in brackets (``j1 [rad]``); streamed page by page (gzip'd
    when the client accepts it)."""
    export = await run_in_threadpool(_open_export, sessions, pass_id)
    next_page = exports.next_page(sessions, export)

    async def body() -> AsyncIterator[bytes]:
        yield exports.csv_header(export)
        while (page := await run_in_threadpool(next_page)) is not None:
            yield exports.csv_rows(page)

    return StreamingResponse(
        body(), media_type=exports.FORMATS["csv"], headers=_attachment(export, "csv")
    )


@router.get(
    "/passes/{pass_id}/telemetry.parquet",
    tags=["telemetry"],
    response_class=Response,
    responses={
        200: {"content": _EXPORT_CONTENT["parquet"], "description": "Every frame, as Parquet"}
    },
)
async def export_telemetry_parquet(
    pass_id: IdPath, _: ViewerDep, sessions: ReadSessionsDep
) -> Response:
    """Every stored frame of the pass in time order, as one Parquet file (zstd): the frame
    layout's columns, typed, each field's unit in its ``unit`` metadata and all of them in
    the file's ``hikoboshi.units`` (JSON)."""
    export = await run_in_threadpool(_open_export, sessions, pass_id)
    spooled, size, _rows = await run_in_threadpool(exports.parquet_file, sessions, export)

    def chunks() -> Iterator[bytes]:
        with spooled:
            while chunk := spooled.read(256 * 1024):
                yield chunk

    return StreamingResponse(
        chunks(),
        media_type=exports.FORMATS["parquet"],
        headers={**_attachment(export, "parquet"), "Content-Length": str(size)},
    )


def _open_export(sessions: sessionmaker[Session], pass_id: str) -> exports.TelemetryExport:
    with sessions() as session:
        return exports.open_export(session, pass_id)
