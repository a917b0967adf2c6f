"""The ground service's settings: passed to :func:`server.app.create_app`, never global.

:meth:`Settings.from_env` is called only by the command line; tests build ``Settings``
directly.
"""

from __future__ import annotations

import ipaddress
import os
from enum import StrEnum
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field, field_validator

__all__ = ["ApiToken", "Role", "Settings"]


class Role(StrEnum):
    VIEWER = "viewer"  # read everything
    OPERATOR = "operator"  # viewer + plan and command
    SPACECRAFT = "spacecraft"  # the link endpoint only


class ApiToken(BaseModel):
    model_config = ConfigDict(frozen=True)
    name: str  # who holds it: written to the audit log
    role: Role


class Settings(BaseModel):
    model_config = ConfigDict(frozen=True)

    data_dir: Path = Path("data")
    #: SQLite under ``data_dir`` unless a URL is given (``postgresql://...``).
    database_url: str | None = None
    #: token -> holder and role
    tokens: dict[str, ApiToken] = Field(default_factory=dict)
    #: SPEC 6: the ground sends each command at least (one-way delay + margin) before its tag
    link_one_way_delay_s: float = 3.0
    uplink_margin_s: float = 2.0
    #: The onboard schedule is kept loaded this far ahead of the onboard clock (onboard s):
    #: every command goes up this long before its tag, and is sent again until
    #: the vehicle acknowledges it, within the vehicle's announced schedule capacity.
    #: Longer than the outages a pass must ride through (SPEC 6).
    uplink_lead_window_s: float = Field(default=120.0, gt=0, le=3600)
    #: A pass's first command is tagged this long (onboard s) after the start, so that it
    #: too can be sent again before its tag if the relay loses it (the runner lengthens it
    #: at high time scales, so that the first command can go up three times).
    uplink_start_lead_s: float = Field(default=30.0, ge=0, le=600)
    command_period_s: float = 0.25
    #: Connections of the readers' pool (REST routes, consoles): kept open, extra when busy,
    #: and how long a request waits for one before 503 ``busy``. The command path (link,
    #: runner, abort) has its own pool of two and never waits behind readers.
    api_pool_size: int = Field(default=8, ge=1, le=100)
    api_pool_overflow: int = Field(default=4, ge=0, le=100)
    api_pool_timeout_s: float = Field(default=3.0, gt=0, le=60)
    #: PostgreSQL: a reader's statement running longer than this is ended (503).
    api_statement_timeout_s: float = Field(default=30.0, gt=0, le=3600)
    #: Capacity lanes (server/api/lanes.py, docs/security.md "Capacity"). Requests with a
    #: viewer's token running at once in the whole server: below the 40 threads
    #: synchronous routes and file streams share, so that viewers never hold every one an
    #: operator's request needs. Past it a request waits its turn (parked, no thread)
    #: while fewer than ``viewer_queue`` wait, at most ``viewer_queue_wait_s``; else 503
    #: ``busy`` with ``Retry-After``.
    viewer_requests_max: int = Field(default=16, ge=1, le=1000)
    viewer_queue: int = Field(default=256, ge=0, le=100_000)
    viewer_queue_wait_s: float = Field(default=10.0, ge=0, le=600)
    #: Heavy reads (a recording, the report, its page and figures, raw telemetry, an
    #: analyses run) in flight for one token holder; past it 429 ``too_many_requests``.
    #: Six: a browser's connections to one host, so that the console's report page, which
    #: loads its figures at once, is never refused its own figures.
    heavy_reads_per_token: int = Field(default=6, ge=1, le=100)
    #: The operators' own connections (their requests and the consoles' hub): no viewer
    #: request uses them, so none can hold the one an operator or a console needs.
    operator_pool_size: int = Field(default=3, ge=1, le=50)
    operator_pool_overflow: int = Field(default=2, ge=0, le=50)
    #: Threads the consoles' hub reads the database in (a subscription's check and
    #: replay of missed messages): its own, never the threads viewer requests share.
    console_db_threads: int = Field(default=2, ge=1, le=32)
    #: Console websockets one token holder may hold at once (any role, any address), and
    #: viewers' consoles from one address; an operator's consoles count only against their
    #: own token's cap, so viewers cannot lock an operator out. Over a cap: closed 1013
    #: (docs/console.md "Connection caps", docs/security.md "Console caps").
    consoles_per_token: int = Field(default=8, ge=1, le=10_000)
    consoles_per_address: int = Field(default=16, ge=1, le=10_000)
    #: The largest MCAP recording ``POST /api/passes/import`` accepts (the 20-minute demo
    #: pass is 14 MB).
    max_import_bytes: int = 256 * 1024 * 1024
    #: The most an imported recording's chunks may hold uncompressed, together (8 x the
    #: upload limit; recordings compress about 4:1), checked before anything is
    #: decompressed; one chunk may hold at most 64 MiB (docs/mcap.md).
    max_import_uncompressed_bytes: int = Field(default=2 * 1024**3, ge=1)
    #: The bytes the spool files of all imports in flight may hold on disk together (two
    #: uploads of the largest size): an import that would take them past it is refused,
    #: 503 ``busy`` with ``Retry-After`` (docs/security.md "Import spools").
    import_spool_budget_bytes: int = Field(default=2 * 256 * 1024 * 1024, ge=1)
    #: CPU-heavy requests (planning, recording downloads, reports, raw telemetry reads) run
    #: in worker processes (server/services/workers.py, docs/planning.md "Limits"):
    #: this many at once, and this many more waiting; past that 503 ``busy`` at once.
    worker_processes: int = Field(default=2, ge=1, le=64)
    worker_queue: int = Field(default=8, ge=0, le=1000)
    #: A planning job is killed past this (s): 504. The worst plan the parameter bounds
    #: allow took 74 s on the 2-core reference machine under load (planner.catalogue).
    plan_deadline_s: float = Field(default=120.0, gt=0, le=3600)
    #: A heavy read (a recording, a report, raw telemetry) is killed past this (s): 504.
    read_deadline_s: float = Field(default=120.0, gt=0, le=3600)
    #: Post-pass work (running a pass's analyses, importing a recording) is killed past
    #: this (s): 504. The 20-minute demo pass takes about 30 s of either on a loaded 2-core
    #: machine.
    post_pass_deadline_s: float = Field(default=600.0, gt=0, le=7200)
    #: Stored recordings, reports and figures (data_dir/artifacts, server/services/
    #: artifacts.py): at most this many bytes in all; past it the least recently served
    #: are deleted (0: nothing is kept, each version is still computed once per burst).
    artifact_cache_bytes: int = Field(default=1024**3, ge=0)
    #: The address space one job may use (bytes, RLIMIT_AS; 0: no limit): past it 503
    #: ``out_of_memory``.
    worker_memory_bytes: int = Field(default=2 * 1024**3, ge=0)
    #: The HTTP edge (server/api/edge.py, docs/security.md). The largest request body any
    #: other route accepts: a larger declared Content-Length is refused (413) unread.
    max_request_bytes: int = Field(default=1024 * 1024, gt=0)
    #: The deepest nesting of arrays and objects a JSON body may have.
    max_json_depth: int = Field(default=32, ge=1, le=1000)
    #: Failed authentications from one address within the window before that address is
    #: answered 429 for the rest of the window; and how many addresses are tracked at most.
    auth_failure_limit: int = Field(default=20, ge=1)
    auth_failure_window_s: float = Field(default=60.0, gt=0)
    auth_tracked_addresses: int = Field(default=10_000, ge=1)
    #: Peers whose ``X-Forwarded-For`` / ``X-Forwarded-Proto`` are believed (addresses or
    #: networks, ``10.0.0.0/8``; ``HIKOBOSHI_TRUSTED_PROXIES``, comma-separated): the reverse
    #: proxy in front of ``serve``. None by default: the client is the peer, whatever it
    #: claims (docs/security.md "Failed authentications").
    trusted_proxies: tuple[str, ...] = ()
    #: ``hikoboshi serve``: a connection whose request head has not fully arrived this long
    #: after its first byte (or after it opened) is closed; idle keep-alive connections are
    #: closed after ``keep_alive_timeout_s``; a request head may be at most this large.
    header_timeout_s: float = Field(default=10.0, gt=0)
    keep_alive_timeout_s: float = Field(default=5.0, gt=0)
    max_header_bytes: int = Field(default=16 * 1024, ge=1024)
    #: Robot descriptions the server plans for besides those shipped under
    #: ``examples/robots/`` (``hikoboshi serve --robot FILE``, ``HIKOBOSHI_ROBOTS``): a plan
    #: request names a robot, never a file (server/services/robots.py).
    robot_files: tuple[Path, ...] = ()
    #: A folder of mission files (``NAME.toml``, docs/missions.md) the server knows besides
    #: those shipped under ``examples/missions/`` (``HIKOBOSHI_MISSIONS_DIR``): a windows or
    #: pass request names a mission, never a file (server/services/missions.py).
    missions_dir: Path | None = None
    #: Check every archived frame and the link's health against the pass's limits and raise
    #: alarms (server/services/alarms.py, docs/alarms.md). Off: no limit alarms (the
    #: vehicle's safing alarm still comes); bench/bench_downlink.py measures the cost.
    limit_checking: bool = True

    # --- malformed messages on the spacecraft link (server/services/malformed.py,
    # docs/protocol.md "Malformed messages") ---------------------------------------------
    #: ground s: one audit row per kind of malformed message per interval; also the
    #: threshold's window
    malformed_interval_s: float = Field(default=5.0, gt=0, le=3600)
    #: ``error`` replies to malformed messages, at most this many a second
    malformed_replies_per_s: float = Field(default=10.0, ge=0, le=1000)
    #: more malformed messages than this on one connection within one interval: the ground
    #: closes it (1008) and the vehicle reconnects
    malformed_close_after: int = Field(default=1000, ge=1)

    @field_validator("trusted_proxies")
    @classmethod
    def _proxies_are_addresses(cls, value: tuple[str, ...]) -> tuple[str, ...]:
        for item in value:
            try:
                ipaddress.ip_network(item, strict=False)
            except ValueError:
                raise ValueError(
                    f"trusted proxy {item!r} is not an IP address or network (10.0.0.0/8)"
                ) from None
        return value

    def resolved_database_url(self) -> str:
        from server.storage.db import sqlite_url

        return self.database_url or sqlite_url(self.data_dir)

    @classmethod
    def from_env(cls) -> Settings:
        """``DATABASE_URL``, ``HIKOBOSHI_DATA_DIR``, ``HIKOBOSHI_TOKENS``
        (``token=name:role,...``), ``HIKOBOSHI_UPLINK_LEAD_WINDOW_S`` (onboard s) and
        ``HIKOBOSHI_ROBOTS`` (robot description files, separated by ``os.pathsep``) and
        ``HIKOBOSHI_LIMIT_CHECKING`` (``0`` turns it off) and ``HIKOBOSHI_TRUSTED_PROXIES``
        (addresses or networks, comma-separated) and ``HIKOBOSHI_MISSIONS_DIR`` (a folder of
        mission files)."""
        tokens: dict[str, ApiToken] = {}
        for item in filter(None, os.environ.get("HIKOBOSHI_TOKENS", "").split(",")):
            token, _, holder = item.partition("=")
            name, _, role = holder.partition(":")
            tokens[token.strip()] = ApiToken(name=name.strip(), role=Role(role.strip()))
        lead = os.environ.get("HIKOBOSHI_UPLINK_LEAD_WINDOW_S")
        #: The worker limits: HIKOBOSHI_WORKER_PROCESSES, HIKOBOSHI_WORKER_QUEUE,
        #: HIKOBOSHI_PLAN_DEADLINE_S, HIKOBOSHI_READ_DEADLINE_S, HIKOBOSHI_WORKER_MEMORY_BYTES;
        #: the lanes': HIKOBOSHI_VIEWER_REQUESTS_MAX, _VIEWER_QUEUE, _VIEWER_QUEUE_WAIT_S and
        #: HIKOBOSHI_HEAVY_READS_PER_TOKEN; the edges' bounds: HIKOBOSHI_IMPORT_SPOOL_BUDGET_BYTES,
        #: HIKOBOSHI_CONSOLES_PER_TOKEN and HIKOBOSHI_CONSOLES_PER_ADDRESS.
        workers = {
            name: os.environ[f"HIKOBOSHI_{name.upper()}"]
            for name in (
                "worker_processes",
                "worker_queue",
                "plan_deadline_s",
                "read_deadline_s",
                "post_pass_deadline_s",
                "worker_memory_bytes",
                "viewer_requests_max",
                "viewer_queue",
                "viewer_queue_wait_s",
                "heavy_reads_per_token",
                "import_spool_budget_bytes",
                "consoles_per_token",
                "consoles_per_address",
            )
            if os.environ.get(f"HIKOBOSHI_{name.upper()}")
        }
        return cls(
            **workers,  # type: ignore[arg-type]
            data_dir=Path(os.environ.get("HIKOBOSHI_DATA_DIR", "data")),
            database_url=os.environ.get("DATABASE_URL") or None,
            tokens=tokens,
            robot_files=tuple(
                Path(p) for p in os.environ.get("HIKOBOSHI_ROBOTS", "").split(os.pathsep) if p
            ),
            uplink_lead_window_s=float(lead)
            if lead
            else cls.model_fields["uplink_lead_window_s"].default,
            trusted_proxies=tuple(
                p.strip()
                for p in os.environ.get("HIKOBOSHI_TRUSTED_PROXIES", "").split(",")
                if p.strip()
            ),
            missions_dir=Path(os.environ["HIKOBOSHI_MISSIONS_DIR"])
            if os.environ.get("HIKOBOSHI_MISSIONS_DIR")
            else None,
            limit_checking=os.environ.get("HIKOBOSHI_LIMIT_CHECKING", "1").strip().lower()
            not in ("0", "false", "no", "off"),
        )
