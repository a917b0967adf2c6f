"""``create_app(settings)``: the ground service. The lifespan opens the database (and runs
its migrations) and closes it; nothing is created at import time."""

from __future__ import annotations

from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from fastapi import FastAPI

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
from server.services.console import ConsoleHub
from server.services.link import GroundLink
from server.services.runner import PassRunner
from server.services.workers import WorkerPool
from server.settings import Settings
from server.storage.db import (
    PoolSizes,
    make_engine,
    read_session_factory,
    session_factory,
    upgrade,
)

__all__ = ["create_app"]


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
        app.state.link = GroundLink(
            sessions=session_factory(link_engine),
            one_way_delay_s=settings.link_one_way_delay_s,
        )
        app.state.runner = PassRunner(link=app.state.link, settings=settings)
        await app.state.runner.recover()
        app.state.console = ConsoleHub(
            publisher=app.state.link.publisher,
            link_status=app.state.link.status,
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
            await app.state.runner.shutdown()
            await app.state.link.close()
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
