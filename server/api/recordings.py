"""``/api/passes/{id}/recording.mcap`` (viewer) and ``/api/passes/import`` (operator): a pass
as one MCAP file, out and in (docs/mcap.md).

The download is written once per content version by a worker process
(:mod:`server.services.workers`) on its own database connection, stored as a file and
streamed from it to every viewer (:mod:`server.services.artifacts`): the server's memory,
threads and connection pool stay the same whatever the pass's size or the number of
viewers; a full pool answers 503 ``busy`` with ``Retry-After``."""

from __future__ import annotations

import re
from typing import Annotated

from fastapi import APIRouter, Depends, Request
from fastapi.responses import Response
from starlette.requests import HTTPConnection

from server.api.deps import (
    ClockDep,
    IdPath,
    OperatorDep,
    SettingsDep,
    ViewerDep,
    WorkersDep,
)
from server.api.errors import HttpError
from server.api.openapi import file_content
from server.api.served import NOT_MODIFIED, ArtifactsDep, serve_artifact
from server.schemas import ERROR_RESPONSES, ErrorPublic
from server.schemas.analyses import PassImportPublic
from server.services.artifacts import ArtifactRef
from server.services.imports import SpoolBudget, SpoolHold, import_file_job
from server.services.jobs import jobs_dir, temporary_path

__all__ = ["router"]

router = APIRouter(prefix="/api/passes", tags=["recordings"], responses=ERROR_RESPONSES)


async def _spools(connection: HTTPConnection) -> SpoolBudget:
    """The imports' spool budget (built by the lifespan, :mod:`server.app`)."""
    spools: SpoolBudget = connection.app.state.import_spools
    return spools


SpoolsDep = Annotated[SpoolBudget, Depends(_spools)]

_BINARY = file_content("application/octet-stream")


def _filename(name: str) -> str:
    """A file name for Content-Disposition: the pass name in safe characters."""
    return (re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._") or "pass")[:100] + ".mcap"


@router.get(
    "/{pass_id}/recording.mcap",
    response_class=Response,
    responses={
        200: {"content": _BINARY, "description": "The pass as one MCAP file"},
        **NOT_MODIFIED,
    },
)
async def download_recording(
    pass_id: IdPath, http: Request, _: ViewerDep, artifacts: ArtifactsDep
) -> Response:
    """Everything stored of the flown pass as MCAP: telemetry, plan with prediction,
    commands with their stages, audit events; plus Foxglove transforms and plot channels.
    Written once per content version (the ``ETag``; ``If-None-Match`` answers 304) by a
    worker process (503 ``busy`` when all are taken, 504 past ``read_deadline_s``) and
    served from the stored file (server/services/artifacts.py)."""
    return await serve_artifact(
        http,
        artifacts,
        ArtifactRef("recording", pass_id),
        "application/octet-stream",
        lambda served: {"Content-Disposition": f'attachment; filename="{_filename(served.label)}"'},
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
    clock: ClockDep,
    spools: SpoolsDep,
) -> PassImportPublic:
    """Store an MCAP pass recording (the body, as ``hikoboshi mcap export`` or
    ``recording.mcap`` writes it) as a new, finished pass marked imported. A file that is
    not a readable recording is refused with the reader's reason; nothing is stored.

    The body is spooled to a file (never held in the server's memory) up to
    ``max_import_bytes``, then read and stored by a worker process on its own connection
    (503 ``busy`` when every worker is taken; past ``post_pass_deadline_s``, 504).

    The spools of all imports in flight hold at most ``import_spool_budget_bytes`` together:
    an upload that would take them past it is refused with 503 ``busy`` and
    ``Retry-After``, before its first byte is read when it declares its length, else as
    soon as it reaches the budget (its partial spool deleted)."""
    limit = settings.max_import_bytes
    declared = request.headers.get("content-length", "")
    if declared.isdigit() and int(declared) > limit:
        raise _too_large(int(declared), limit)
    with spools.hold() as hold:
        if declared.isdigit():
            hold.take(int(declared))  # admitted whole, or refused unread
        return await _spool_and_import(request, settings, who.name, workers, clock, hold)


async def _spool_and_import(
    request: Request,
    settings: SettingsDep,
    actor: str,
    workers: WorkersDep,
    clock: ClockDep,
    hold: SpoolHold,
) -> PassImportPublic:
    limit = settings.max_import_bytes
    path = temporary_path(jobs_dir(settings.data_dir), ".mcap")
    try:
        size = 0
        with path.open("wb") as spool:
            async for chunk in request.stream():
                size += len(chunk)
                if size > limit:
                    raise _too_large(size, limit)
                hold.take(size)
                spool.write(chunk)
        imported: PassImportPublic = await workers.run_written(
            import_file_job,
            settings.resolved_database_url(),
            str(path),
            actor,
            settings.max_import_uncompressed_bytes,
            clock.time_ns(),
            deadline_s=settings.post_pass_deadline_s,
            what="the import",
            client=request,
        )
        return imported
    finally:
        path.unlink(missing_ok=True)


def _too_large(size: int, limit: int) -> HttpError:
    return HttpError(
        413, "recording_too_large", f"upload of {size} bytes exceeds the limit of {limit} bytes"
    )
