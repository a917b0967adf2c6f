"""``/api/passes/{id}/recording.mcap`` (viewer) and ``/api/passes/import`` (operator): a pass
as one MCAP file, out and in (docs/mcap.md).

The download is written by a worker process (:mod:`server.services.workers`) on its own
database connection, to a temporary file that the route streams and deletes: the server's
memory, threads and connection pool stay the same whatever the pass's size or the number
of viewers; a full pool answers 503 ``busy`` with ``Retry-After``."""

from __future__ import annotations

import re

from fastapi import APIRouter, Request
from fastapi.responses import Response, StreamingResponse

from server.api.deps import (
    ClockDep,
    OperatorDep,
    PublisherDep,
    SettingsDep,
    ViewerDep,
    WorkersDep,
)
from server.api.errors import HttpError
from server.schemas import ERROR_RESPONSES, ErrorPublic, PassImportPublic
from server.services import recordings as service
from server.services.imports import import_file_job
from server.services.jobs import (
    jobs_dir,
    read_session_job,
    stream_file,
    temporary_path,
)

__all__ = ["router"]

router = APIRouter(prefix="/api/passes", tags=["recordings"], responses=ERROR_RESPONSES)

_BINARY = {"application/octet-stream": {"schema": {"type": "string", "format": "binary"}}}


def _filename(name: str) -> str:
    """A file name for Content-Disposition: the pass name in safe characters."""
    return (re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._") or "pass")[:100] + ".mcap"


@router.get(
    "/{pass_id}/recording.mcap",
    response_class=Response,
    responses={200: {"content": _BINARY, "description": "The pass as one MCAP file"}},
)
async def download_recording(
    pass_id: str, http: Request, settings: SettingsDep, _: ViewerDep, workers: WorkersDep
) -> Response:
    """Everything stored of the flown pass as MCAP: telemetry, plan with prediction,
    commands with their stages, audit events; plus Foxglove transforms and plot channels.
    Written by a worker process (503 ``busy`` when all are taken, 504 past
    ``read_deadline_s``) and streamed from a temporary file."""
    path = temporary_path(jobs_dir(settings.data_dir), ".mcap")
    name = await workers.run(
        read_session_job,
        settings.resolved_database_url(),
        service.write_recording,
        pass_id=pass_id,
        path=str(path),
        robot_files=tuple(str(p) for p in settings.robot_files),
        deadline_s=settings.read_deadline_s,
        what=f"the recording of pass {pass_id}",
        client=http,
        cleanup=path,
    )
    chunks, size = stream_file(path)
    return StreamingResponse(
        chunks,
        media_type="application/octet-stream",
        headers={
            "Content-Disposition": f'attachment; filename="{_filename(name)}"',
            "Content-Length": str(size),
        },
    )


@router.post(
    "/import",
    status_code=201,
    response_model=PassImportPublic,
    openapi_extra={"requestBody": {"required": True, "content": _BINARY}},
    responses={413: {"model": ErrorPublic, "description": "The upload exceeds the size limit"}},
)
async def import_recording(
    request: Request,
    settings: SettingsDep,
    who: OperatorDep,
    workers: WorkersDep,
    publisher: PublisherDep,
    clock: ClockDep,
) -> PassImportPublic:
    """Store an MCAP pass recording (the body, as ``hikoboshi mcap export`` or
    ``recording.mcap`` writes it) as a new, finished pass marked imported. A file that is
    not a readable recording is refused with the reader's reason; nothing is stored.

    The body is spooled to a file (never held in the server's memory) up to
    ``max_import_bytes``, then read and stored by a worker process on its own connection
    (503 ``busy`` when every worker is taken; past ``post_pass_deadline_s``, 504)."""
    limit = settings.max_import_bytes
    declared = request.headers.get("content-length", "")
    if declared.isdigit() and int(declared) > limit:
        raise _too_large(int(declared), limit)
    path = temporary_path(jobs_dir(settings.data_dir), ".mcap")
    try:
        size = 0
        with path.open("wb") as spool:
            async for chunk in request.stream():
                size += len(chunk)
                if size > limit:
                    raise _too_large(size, limit)
                spool.write(chunk)
        imported, events = await workers.run(
            import_file_job,
            settings.resolved_database_url(),
            str(path),
            who.name,
            settings.max_import_uncompressed_bytes,
            clock.time_ns(),
            deadline_s=settings.post_pass_deadline_s,
            what="the import",
            client=request,
        )
        publisher.publish(events)
        return imported
    finally:
        path.unlink(missing_ok=True)


def _too_large(size: int, limit: int) -> HttpError:
    return HttpError(
        413, "recording_too_large", f"upload of {size} bytes exceeds the limit of {limit} bytes"
    )
