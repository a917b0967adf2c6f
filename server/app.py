"""``create_app(settings)``: the ground service, and its composition root.

The lifespan opens the database (and runs its migrations) and builds the live path's
services as siblings (:func:`build_live_path`: the clock, the database worker, the
publisher, the downlink, the link, the command trackers' factory and the runner), then the
consoles' hub and the worker pool, each handed what it needs in its constructor; the routes
reach them through the typed dependencies of :mod:`server.api.deps`. Nothing is created at
import time."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from dataclasses import dataclass

from fastapi import FastAPI
from sqlalchemy.orm import Session, sessionmaker

from server.api import analyses as analyses_api
from server.api import console as console_api
from server.api import control as control_api
from server.api import link as link_api
from server.api import model as model_api
from server.api import passes as passes_api
from server.api import plans as plans_api
from server.api import recordings as recordings_api
from server.api import robots as robots_api
from server.api import telemetry as telemetry_api
from server.api import web as web_api
from server.api.edge import install_edge
from server.api.errors import install_error_handlers
from server.services.clock import Clock, SystemClock
from server.services.console import ConsoleHub
from server.services.dbworker import Database, Publisher
from server.services.downlink import GroundDownlink
from server.services.link import GroundLink
from server.services.runner import PassRunner
from server.services.tracker import Trackers
from server.services.workers import WorkerPool
from server.settings import Settings
from server.storage.db import (
    PoolSizes,
    make_engine,
    read_session_factory,
    session_factory,
    upgrade,
)

__all__ = ["LivePath", "build_live_path", "create_app"]


@dataclass(frozen=True)
class LivePath:
    """The services of the command path (one database worker, on its own connections)."""

    clock: Clock
    publisher: Publisher
    db: Database
    downlink: GroundDownlink
    link: GroundLink
    trackers: Trackers
    runner: PassRunner

    async def close(self) -> None:
        """After the runner's shutdown: the link's socket, then the database worker."""
        await self.link.close()
        await self.db.drain()
        await asyncio.to_thread(self.db.close)


def build_live_path(
    *, sessions: sessionmaker[Session], settings: Settings, clock: Clock
) -> LivePath:
    """The live path's services, each handed its collaborators. The downlink sends its
    acknowledgements through the link's session (bound late: the link routes telemetry to
    the downlink)."""
    publisher = Publisher()
    db = Database(sessions, publisher)
    delay_s = settings.link_one_way_delay_s

    async def send(text: str) -> bool:
        return await link.send(text)

    downlink = GroundDownlink(
        db=db, publisher=publisher, clock=clock, send=send, time_scale=lambda: link.time_scale
    )
    link = GroundLink(db=db, downlink=downlink, clock=clock, one_way_delay_s=delay_s)
    trackers = Trackers(link=link, db=db, clock=clock, one_way_delay_s=delay_s)
    runner = PassRunner(
        link=link,
        downlink=downlink,
        db=db,
        publisher=publisher,
        trackers=trackers,
        settings=settings,
        clock=clock,
    )
    return LivePath(clock, publisher, db, downlink, link, trackers, runner)


def create_app(settings: Settings) -> FastAPI:
    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        url = settings.resolved_database_url()
        # Two pools on one database: the command path's own (link worker, runner, abort)
        # and the readers' (routes, consoles), so no number of readers takes a connection
        # the link needs (docs/security.md).
        link_engine = make_engine(url, pool=PoolSizes(size=2, overflow=1, timeout_s=30.0))
        upgrade(link_engine)
        engine = make_engine(
            url,
            pool=PoolSizes(
                size=settings.api_pool_size,
                overflow=settings.api_pool_overflow,
                timeout_s=settings.api_pool_timeout_s,
                statement_timeout_s=settings.api_statement_timeout_s,
            ),
        )
        app.state.settings = settings
        app.state.engine = engine
        app.state.link_engine = link_engine
        app.state.sessions = session_factory(engine)
        app.state.read_sessions = read_session_factory(engine)
        live = build_live_path(
            sessions=session_factory(link_engine), settings=settings, clock=SystemClock()
        )
        app.state.clock = live.clock
        app.state.publisher = live.publisher
        app.state.db = live.db
        app.state.downlink = live.downlink
        app.state.link = live.link
        app.state.runner = live.runner
        await live.runner.recover()
        app.state.console = ConsoleHub(
            publisher=live.publisher,
            link_status=live.link.status,
            sessions=app.state.read_sessions,
        )
        app.state.console.start()
        app.state.workers = WorkerPool(
            workers=settings.worker_processes,
            queue=settings.worker_queue,
            memory_bytes=settings.worker_memory_bytes or None,
        )
        await app.state.workers.start()
        try:
            yield
        finally:
            await app.state.workers.close()  # kills running jobs
            await app.state.console.close()
            await live.runner.shutdown()
            await live.close()
            engine.dispose()
            link_engine.dispose()

    app = FastAPI(
        title="Hikoboshi ground service",
        version="0.1.0",
        description="Plans, passes, the 4 Hz uplink, the telemetry archive and the link.",
        lifespan=lifespan,
    )
    install_error_handlers(app)
    install_edge(app, settings)  # auth, limits and text checks before any route
    app.include_router(link_api.router)
    app.include_router(console_api.router)
    app.include_router(control_api.router)
    app.include_router(plans_api.router)
    app.include_router(recordings_api.router)  # before passes: /api/passes/import
    app.include_router(passes_api.router)
    app.include_router(analyses_api.router)
    app.include_router(telemetry_api.router)
    app.include_router(model_api.router)
    app.include_router(robots_api.router)
    app.include_router(web_api.make_router())

    @app.get("/api/health", tags=["service"])
    def health() -> dict[str, str]:
        return {"status": "ok"}

    return app
