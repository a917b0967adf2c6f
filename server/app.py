"""``create_app(settings)``: the ground service, and its composition root.

The lifespan opens the database (and runs its migrations) and builds the live path's
services as siblings (:func:`build_live_path`: the clock, the database worker, the
publisher, the downlink, the link, the command trackers' factory, the runner and the
alarms), then the
consoles' hub and the worker pool, each handed what it needs in its constructor; the routes
reach them through the typed dependencies of :mod:`server.api.deps`. Nothing is created at
import time."""

from __future__ import annotations

import asyncio
import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import IO

from fastapi import FastAPI
from sqlalchemy import Engine, make_url
from sqlalchemy.orm import Session, sessionmaker

from server.api import alarms as alarms_api
from server.api import analyses as analyses_api
from server.api import console as console_api
from server.api import control as control_api
from server.api import link as link_api
from server.api import missions as missions_api
from server.api import model as model_api
from server.api import passes as passes_api
from server.api import plans as plans_api
from server.api import ready as ready_api
from server.api import recordings as recordings_api
from server.api import robots as robots_api
from server.api import telemetry as telemetry_api
from server.api import web as web_api
from server.api import windows as windows_api
from server.api.compression import Compression
from server.api.edge import install_edge
from server.api.errors import install_error_handlers
from server.api.foxglove_gate import close_foxglove, open_foxglove
from server.api.metrics import connect_metrics, install_metrics
from server.api.openapi import document_problems, operation_id
from server.api.stopping import AnswerWhenStopping
from server.operations.windows import start_lead_s
from server.services._console_backfill import backfill
from server.services._console_jetstream import AcrossGrounds
from server.services.alarms import AlarmService
from server.services.artifacts import ArtifactStore
from server.services.authority import (
    CommandAuthority,
    LeasePolicy,
    ground_name,
    hold_sqlite_file,
)
from server.services.clock import Clock, SystemClock
from server.services.console import ConsoleHub
from server.services.console_seats import ConsoleSeats
from server.services.dbworker import Database, Publisher, frames_apart_for
from server.services.downlink import GroundDownlink
from server.services.event_lines import log_event
from server.services.event_log import publish_on_commit
from server.services.ground_status import ground_status
from server.services.imports import SpoolBudget
from server.services.jetstream import BusConfig, LiveBus
from server.services.link import GroundLink
from server.services.malformed import MalformedPolicy
from server.services.readiness import ReadinessProbe
from server.services.runner import PassRunner
from server.services.tracker import Trackers
from server.services.workers import WorkerPool
from server.settings import Settings
from server.stopping import STOP_DATABASE_WAIT_S, GroundServer, begin_shutdown
from server.storage.db import (
    PoolSizes,
    make_engine,
    read_session_factory,
    session_factory,
    upgrade,
)

log = logging.getLogger("hikoboshi.ground")

__all__ = ["GroundServer", "LivePath", "begin_shutdown", "build_live_path", "create_app"]

#: s: a takeover publishes the frames the ground gone did not publish for this long at most
BACKFILL_GUARD_S = 5.0


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
    alarms: AlarmService

    async def close(self) -> None:
        """After the runner's shutdown: the link's socket, the alarms' last writes, then the
        database worker."""
        await self.link.close()
        await self.alarms.close()
        await self.db.drain()
        await asyncio.to_thread(self.db.close)


def build_live_path(
    *,
    sessions: sessionmaker[Session],
    settings: Settings,
    clock: Clock,
    authority: CommandAuthority | None = None,
) -> LivePath:
    """The live path's services, each handed its collaborators. The downlink sends its
    acknowledgements through the link's session (bound late: the link routes telemetry to
    the downlink). The alarms subscribe to the publisher first, so a frame batch is checked
    before the consoles get it. With ``authority`` (the service), every transaction of the
    database worker is fenced by the command lease and the runner commands only while this
    ground holds it."""
    publisher = Publisher()
    db = Database(
        sessions,
        publisher,
        frames_apart=frames_apart_for(sessions),
        journal_max=settings.database_journal_max,
    )
    if authority is not None:
        db.fence = authority.fence
    delay_s = settings.link_one_way_delay_s

    async def send(text: str) -> bool:
        return await link.send(text)

    downlink = GroundDownlink(
        db=db, publisher=publisher, clock=clock, send=send, time_scale=lambda: link.time_scale
    )
    link = GroundLink(
        db=db,
        downlink=downlink,
        clock=clock,
        one_way_delay_s=delay_s,
        malformed=MalformedPolicy(
            interval_s=settings.malformed_interval_s,
            replies_per_s=settings.malformed_replies_per_s,
            unusable_after=settings.malformed_unusable_after,
        ),
    )
    trackers = Trackers(link=link, db=db, clock=clock, one_way_delay_s=delay_s)
    alarms = AlarmService(
        db=db, publisher=publisher, clock=clock, downlink=downlink, link=link, settings=settings
    )
    runner = PassRunner(
        link=link,
        downlink=downlink,
        db=db,
        publisher=publisher,
        trackers=trackers,
        settings=settings,
        clock=clock,
        start_lead=partial(start_lead_s, settings),
        alarms=alarms,
        authority=authority,
    )
    alarms.start()
    publisher.subscribe(log_event)  # the operator's log lines, once committed
    return LivePath(clock, publisher, db, downlink, link, trackers, runner, alarms)


def _authority(settings: Settings, url: str) -> tuple[CommandAuthority, Engine, IO[str] | None]:
    """The command lease's keeper on a connection of its own; on an SQLite file, first the
    file's exclusive lock (a second ground is refused here, before anything is written:
    :class:`~server.services.authority.SecondGround`)."""
    held: IO[str] | None = None
    parsed = make_url(url)
    if parsed.get_backend_name() == "sqlite":
        database = parsed.database or ""
        if database and database != ":memory:" and not database.startswith("file:"):
            held = hold_sqlite_file(Path(database))
    engine = make_engine(
        url, pool=PoolSizes(size=1, overflow=0, timeout_s=2.0, statement_timeout_s=2.0)
    )
    policy = LeasePolicy(
        name=settings.command_lease,
        holder=ground_name(settings.ground_name),
        ttl_s=settings.lease_ttl_s,
        renew_s=settings.lease_renew_s,
        exclusive=held is not None,
    )
    return CommandAuthority(session_factory(engine), policy), engine, held


async def _across_grounds(
    settings: Settings, authority: CommandAuthority, publisher: Publisher
) -> AcrossGrounds | None:
    """With ``nats_url``: this ground's live messages to JetStream and its consoles' streams
    from there (docs/console.md "Across grounds"); without, None (one ground's consoles)."""
    if settings.nats_url is None:
        return None
    config = BusConfig(
        url=settings.nats_url,
        stream=settings.nats_stream,
        max_age_s=settings.nats_max_age_s,
        max_bytes=settings.nats_max_bytes,
        lease=settings.command_lease,
    )
    bus = LiveBus(config, name=authority.policy.holder)
    await bus.open()
    across = AcrossGrounds(bus, commanding=lambda: authority.holder)
    await across.open(publisher)
    log.info("consoles across grounds: JetStream stream %r at %s", config.stream, config.url)
    return across


async def _keep_command(
    live: LivePath,
    authority: CommandAuthority,
    commanding: bool,
    across: AcrossGrounds | None,
    sessions: sessionmaker[Session],
) -> None:
    """Command the vehicle if this ground took the lease at its start (the recovery after a
    restart), else be a standby; then keep the lease: a standby that takes it over from a
    holder gone first publishes what that ground archived and never published (with NATS),
    then runs the same recovery; a holder whose lease was taken stands down."""

    async def took_over() -> None:
        log.warning(
            "took over the command lease (token %s): resuming the passes left unfinished",
            authority.status()["token"],
            extra={"fields": {"event": "takeover"}},
        )
        try:
            await published_what_was_left()
        finally:
            authority.settled()  # the vehicle's link is taken from here
        await live.runner.recover()

    async def published_what_was_left() -> None:
        if across is None:
            return
        try:
            await asyncio.wait_for(backfill(across, sessions), BACKFILL_GUARD_S)
        except Exception:
            log.exception("the frames of the ground gone were not published")

    async def lost(reason: str) -> None:
        await live.runner.stand_down()
        await live.link.going_away(1013, "standby: another ground holds the command lease")

    if commanding:  # after a restart: what this ground stored before it died, unpublished
        await published_what_was_left()
        await live.runner.recover()
    else:
        log.warning(
            "standby: %s holds the command lease %r; this ground serves reads and consoles "
            "and takes over when it is gone",
            authority.status().get("lease_holder") or "another ground",
            authority.policy.name,
            extra={"fields": {"event": "standby"}},
        )
    authority.start(on_acquired=took_over, on_lost=lost)


def _api_engine(settings: Settings, url: str, size: int, overflow: int) -> Engine:
    """An engine for the API's requests: ``size`` (+ ``overflow``) connections, the API's
    wait for one and its statements' timeout."""
    return make_engine(
        url,
        pool=PoolSizes(
            size=size,
            overflow=overflow,
            timeout_s=settings.api_pool_timeout_s,
            statement_timeout_s=settings.api_statement_timeout_s,
        ),
    )


def create_app(settings: Settings) -> FastAPI:
    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        url = settings.resolved_database_url()
        authority, lease_engine, held = _authority(settings, url)
        # Two pools on one database: the command path's own (the link's database worker and,
        # on PostgreSQL, its frames' worker: a connection each; the runner, abort)
        # and the readers' (routes, consoles), so no number of readers takes a connection
        # the link needs (docs/security.md).
        link_engine = make_engine(url, pool=PoolSizes(size=2, overflow=1, timeout_s=30.0))
        upgrade(link_engine)
        engine = _api_engine(settings, url, settings.api_pool_size, settings.api_pool_overflow)
        # And the operators' own (their requests, the consoles' hub): no viewer holds one
        # (server/api/lanes.py).
        operator_engine = _api_engine(
            settings, url, settings.operator_pool_size, settings.operator_pool_overflow
        )
        app.state.settings = settings
        app.state.engine = engine
        app.state.link_engine = link_engine
        app.state.operator_engine = operator_engine
        app.state.sessions = session_factory(engine)
        app.state.read_sessions = read_session_factory(engine)
        app.state.operator_sessions = session_factory(operator_engine)
        app.state.operator_read_sessions = read_session_factory(operator_engine)
        live = build_live_path(
            sessions=session_factory(link_engine),
            settings=settings,
            clock=SystemClock(),
            authority=authority,
        )
        # what a request's transaction writes (a pass scheduled, an auth block) is published
        # when it commits, as the command path's is (its factory is hooked by its worker)
        for writing in (app.state.sessions, app.state.operator_sessions):
            publish_on_commit(writing, live.publisher)
        app.state.authority = authority
        live.link.ground_status = ground_status(authority, live.db)
        # before the first transaction of the command path: each is fenced by the lease
        commanding = await asyncio.to_thread(authority.try_acquire)
        app.state.clock = live.clock
        app.state.publisher = live.publisher
        app.state.db = live.db
        app.state.downlink = live.downlink
        app.state.link = live.link
        app.state.runner = live.runner
        app.state.alarms = live.alarms
        await live.alarms.load_vehicle_alarms()
        # before the recovery: what it writes (pass_resumed) reaches every ground's consoles
        across = await _across_grounds(settings, authority, live.publisher)
        app.state.across = across
        await _keep_command(  # docs/operations.md
            live, authority, commanding, across, app.state.operator_read_sessions
        )
        app.state.console = ConsoleHub(
            publisher=live.publisher,
            link_status=live.link.status,
            sessions=app.state.operator_read_sessions,
            replay_sessions=app.state.read_sessions,  # a whole recording: a viewer's read
            db_threads=settings.console_db_threads,
            clock=live.clock,
            across=across,
        )
        app.state.console.start()
        app.state.console_seats = ConsoleSeats(
            per_token=settings.consoles_per_token, per_address=settings.consoles_per_address
        )
        app.state.workers = WorkerPool(
            workers=settings.worker_processes,
            queue=settings.worker_queue,
            memory_bytes=settings.worker_memory_bytes or None,
            publisher=live.publisher,
        )
        await app.state.workers.start()
        # Heavy artifacts (recording, report, figures): computed once, served from files.
        app.state.artifacts = ArtifactStore(
            root=settings.data_dir / "artifacts",
            max_bytes=settings.artifact_cache_bytes,
            sessions=app.state.read_sessions,
            workers=app.state.workers,
            url=url,
            deadline_s=settings.read_deadline_s,
            robot_files=tuple(str(p) for p in settings.robot_files),
        )
        app.state.artifacts.start()
        app.state.import_spools = SpoolBudget(settings.import_spool_budget_bytes)
        app.state.readiness = ReadinessProbe(url)  # GET /api/ready (server/api/ready.py)
        connect_metrics(app.state)  # GET /metrics reads the services (server/api/metrics.py)
        app.state.foxglove, app.state.foxglove_gate = open_foxglove(
            settings, live.publisher, app.state.read_sessions
        )
        try:
            yield
        finally:
            close_foxglove(app.state.foxglove, app.state.foxglove_gate)
            app.state.readiness.close()
            await app.state.artifacts.close()
            await app.state.workers.close()  # kills running jobs
            await app.state.console.close()
            live.db.give_up(STOP_DATABASE_WAIT_S)  # if begin_shutdown has not already
            await live.runner.shutdown()
            await live.close()
            if across is not None:  # after the last write: ground_stopped is published
                await across.close()
            await authority.close()  # after the last write: a standby takes over at once
            lease_engine.dispose()
            if held is not None:
                held.close()
            engine.dispose()
            operator_engine.dispose()
            link_engine.dispose()

    app = FastAPI(
        title="Hikoboshi ground service",
        version="0.1.0",
        description="Plans, passes, the 4 Hz uplink, the telemetry archive and the link.",
        lifespan=lifespan,
        generate_unique_id_function=operation_id,  # start_pass, list_passes, ...
        docs_url=None,  # /docs is served from the console's build (server/api/web.py)
        redoc_url=None,  # ReDoc would load from a CDN: /docs and /openapi.json are the docs
    )
    install_error_handlers(app)
    document_problems(app)  # errors are application/problem+json (RFC 9457)
    install_edge(app, settings)  # auth, limits and text checks before any route
    app.add_middleware(Compression)  # gzip over 1 KB when accepted (server/api/compression.py)
    install_metrics(app)  # times every request, refused ones too; GET /metrics
    app.add_middleware(AnswerWhenStopping)  # outermost: a request cut short answers JSON
    app.include_router(link_api.router)
    app.include_router(console_api.router)
    app.include_router(control_api.router)
    app.include_router(plans_api.router)
    app.include_router(recordings_api.router)  # before passes: /api/passes/import
    app.include_router(passes_api.router)
    app.include_router(analyses_api.router)
    app.include_router(alarms_api.router)
    app.include_router(telemetry_api.router)
    app.include_router(model_api.router)
    app.include_router(robots_api.router)
    app.include_router(windows_api.router)
    app.include_router(missions_api.router)
    app.include_router(ready_api.router)
    app.include_router(web_api.make_router())

    @app.get("/api/health", tags=["service"])
    async def health() -> dict[str, str]:
        """Liveness: on the event loop, no thread and no database (the live lane); and
        whether this ground commands the vehicle (``holder``) or is a ``standby``."""
        authority: CommandAuthority | None = getattr(app.state, "authority", None)
        role = "starting" if authority is None else authority.status()["role"]
        return {"status": "ok", "command": role}

    return app
