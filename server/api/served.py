"""Serving a pass's stored artifacts (:mod:`server.services.artifacts`) over HTTP: the
version as the ``ETag``, ``If-None-Match`` answered 304 before anything is computed or
read, the file streamed with its length."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Annotated, Any

from fastapi import Depends, Request
from fastapi.responses import Response, StreamingResponse
from starlette.requests import HTTPConnection

from server.api.compression import send_as_stored
from server.services.artifacts import ArtifactRef, ArtifactStore, Served

__all__ = ["NOT_MODIFIED", "ArtifactsDep", "serve_artifact"]

#: A viewer's token fetched it: no shared cache keeps it; a browser revalidates each time.
_CACHE_CONTROL = "private, no-cache"
#: The 304 of the artifact routes, for their OpenAPI ``responses``.
NOT_MODIFIED: dict[int | str, dict[str, Any]] = {
    304: {"description": "Not modified: the ETag given in If-None-Match is still current"}
}


async def _artifacts(connection: HTTPConnection) -> ArtifactStore:
    store: ArtifactStore = connection.app.state.artifacts
    return store


#: The artifact store the lifespan built (server/app.py).
ArtifactsDep = Annotated[ArtifactStore, Depends(_artifacts)]


def _matches(header: str | None, version: str) -> bool:
    """Whether ``If-None-Match`` names ``version`` (weak or strong) or is ``*``."""
    if not header:
        return False
    for tag in header.split(","):
        tag = tag.strip().removeprefix("W/")
        if tag == "*" or tag.strip('"') == version:
            return True
    return False


async def serve_artifact(
    http: Request,
    store: ArtifactStore,
    ref: ArtifactRef,
    media_type: str,
    headers: Mapping[str, str] | Callable[[Served], Mapping[str, str]] = {},  # noqa: B006
) -> Response:
    """The artifact ``ref`` as a response of ``media_type`` with ``headers`` (or the
    headers a function of the served artifact gives), or 304 when the request's
    ``If-None-Match`` holds the current version."""
    version = await store.version(ref)
    if _matches(http.headers.get("if-none-match"), version.key):
        return Response(
            status_code=304,
            headers={"ETag": f'"{version.key}"', "Cache-Control": _CACHE_CONTROL},
        )
    served = await store.fetch(ref, version, client=http)
    send_as_stored(http)  # its length and ETag as stored, never gzip'd on the way
    extra = headers(served) if callable(headers) else headers
    return StreamingResponse(
        served.chunks(),
        media_type=media_type,
        headers={
            **extra,
            "Content-Length": str(served.size),
            "ETag": f'"{served.version}"',
            "Cache-Control": _CACHE_CONTROL,
        },
    )
