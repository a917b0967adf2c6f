"""``create_app(settings)``: the ground service. The lifespan opens the database (and runs
its migrations) and closes it; nothing is created at import time."""

from __future__ import annotations

from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from fastapi import FastAPI

from server.errors import install_error_handlers
from server.settings import Settings
from server.storage.db import make_engine, session_factory, upgrade

__all__ = ["create_app"]


def create_app(settings: Settings) -> FastAPI:
    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        engine = make_engine(settings.resolved_database_url())
        upgrade(engine)
        app.state.settings = settings
        app.state.engine = engine
        app.state.sessions = session_factory(engine)
        try:
            yield
        finally:
            engine.dispose()

    app = FastAPI(
        title="Hikoboshi ground service",
        version="0.1.0",
        description="Plans, passes, the 4 Hz uplink, the telemetry archive and the link.",
        lifespan=lifespan,
    )
    install_error_handlers(app)

    @app.get("/api/health", tags=["service"])
    def health() -> dict[str, str]:
        return {"status": "ok"}

    return app
