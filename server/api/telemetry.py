"""``/api/passes/{id}/telemetry`` and ``/api/events``: the archive, read-only (viewer).

Raw telemetry (up to :data:`MAX_ROWS` rows of a range that may span a whole pass) is read
in a worker process (:mod:`server.services.workers`) on its own database connection; a
full pool answers 503 ``busy`` with ``Retry-After``, past ``read_deadline_s`` 504. Buckets
(at most ``MAX_BUCKETS`` aggregates computed by the database) stay in the server."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query, Request
from starlette.concurrency import run_in_threadpool

from server.api.deps import IdPath, SessionDep, SettingsDep, ViewerDep, WorkersDep
from server.schemas import ERROR_RESPONSES, MAX_NS, EventsPublic, SafeLine, TelemetryPublic
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
) -> TelemetryPublic:
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
    return await workers.run(
        read_session_job,
        settings.resolved_database_url(),
        service.telemetry,
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


@router.get("/events", response_model=EventsPublic, tags=["events"])
def list_events(
    session: SessionDep,
    _: ViewerDep,
    pass_id: Annotated[SafeLine | None, Query(max_length=64)] = None,
    offset: Annotated[int, Query(ge=0, le=1_000_000_000)] = 0,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
) -> EventsPublic:
    """The audit log in time order, of one pass if ``pass_id`` is given."""
    return service.list_events(session=session, pass_id=pass_id, offset=offset, limit=limit)
