"""``GET /metrics``: the ground's Prometheus metrics (:mod:`server.services.metrics`), for
a viewer's token (docs/security.md "Metrics"); and the middleware that times each HTTP
request by route.

:func:`install_metrics` is all the application does: it makes the registry
(``app.state.metrics``), adds the middleware and the route, and, once the application has
started, points the collector at the services (:func:`connect_metrics`).
"""

from __future__ import annotations

import asyncio
import logging
import time
from typing import Any

from fastapi import APIRouter, FastAPI, Request
from fastapi.responses import Response
from prometheus_client.exposition import choose_encoder
from sqlalchemy.exc import SQLAlchemyError
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from server.api.deps import ViewerDep
from server.services.metrics import GroundMetrics
from server.services.record_counts import RecordCounter

__all__ = ["METRICS_PATH", "RequestTimer", "connect_metrics", "install_metrics"]

METRICS_PATH = "/metrics"

router = APIRouter()
log = logging.getLogger("hikoboshi.ground.metrics")

#: The methods named in the latency's labels; any other is ``other`` (a client chooses the
#: method: its labels must not grow without bound).
_METHODS = frozenset({"GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS"})


@router.get(METRICS_PATH, include_in_schema=False)
async def metrics(request: Request, _viewer: ViewerDep) -> Response:
    """The Prometheus exposition (OpenMetrics when the ``Accept`` header asks for it); its
    figures are computed now, on the event loop, from what the services hold, but the
    archive's counts: those are asked of the database in a thread when older than a few
    seconds (a database that does not answer leaves them out, and says so in the log)."""
    counter: RecordCounter | None = getattr(request.app.state, "record_counter", None)
    if counter is not None:
        try:
            await asyncio.to_thread(counter.refresh)
        except SQLAlchemyError as exc:
            counter.latest = None
            log.warning("metrics: the archive's counts are left out: %s", exc)
    registry = request.app.state.metrics.registry
    # OpenMetrics for a client that asks for it (Prometheus does), else the text format
    encode, media_type = choose_encoder(request.headers.get("accept", ""))
    return Response(encode(registry), media_type=media_type)


class RequestTimer:
    """Times each HTTP request (wall s, to the end of its response) into
    ``hikoboshi_http_request_duration_seconds`` by method, route template (``/api/passes/
    {pass_id}``; ``unmatched`` when no route took it: refused at the edge, or no such
    path) and status class (``2xx``); every label from a bounded set."""

    def __init__(self, app: ASGIApp, metrics: GroundMetrics) -> None:
        self.app = app
        self.metrics = metrics

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        began = time.perf_counter()
        status = 0

        async def timed_send(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = int(message["status"])
            await send(message)

        try:
            await self.app(scope, receive, timed_send)
        finally:
            route = scope.get("route")
            template = getattr(route, "path", None) or "unmatched"
            label = f"{status // 100}xx" if status else "none"
            method = scope["method"] if scope["method"] in _METHODS else "other"
            self.metrics.request_seconds.labels(method, template, label).observe(
                time.perf_counter() - began
            )


def install_metrics(app: FastAPI) -> GroundMetrics:
    """The registry, the request timer (outermost: every request, refused ones too) and
    ``GET /metrics``."""
    metrics = GroundMetrics()
    app.state.metrics = metrics
    app.add_middleware(RequestTimer, metrics=metrics)
    app.include_router(router)
    return metrics


def connect_metrics(state: Any) -> None:
    """Point the collector at the started application's services (``app.state``), and the
    link's database worker's commits at their histogram."""
    metrics: GroundMetrics = state.metrics
    sources = metrics.sources
    sources.link_status = state.link.status
    sources.command_stages = state.runner.command_stages
    sources.uplink_leads_s = state.runner.uplink_leads_s
    workers = state.workers
    sources.workers = lambda: (workers.running, workers.admitted, workers.queue)
    sources.consoles = lambda: state.console.clients
    authority = state.authority
    sources.authority = lambda: {
        **authority.status(),
        "acquisitions": authority.acquisitions,
        "losses": authority.losses,
        "renewal_failures": authority.renewal_failures,
    }
    db = state.db
    sources.database = lambda: db.outage.status(db.journal)

    def foxglove() -> tuple[int, int] | None:  # started after this, when it runs
        live = getattr(state, "foxglove", None)
        return None if live is None else (live.dropped, live.sent)

    sources.foxglove = foxglove
    counter = state.record_counter = RecordCounter(state.read_sessions)
    sources.records = lambda: counter.latest
    sources.data_dir = state.settings.data_dir
    state.db.on_commit = metrics.db_commit_seconds.observe
