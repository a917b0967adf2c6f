"""The ground service's settings: passed to :func:`server.app.create_app`, never global.

Built directly (``Settings(data_dir=...)``, as the tests do), a ``Settings`` holds what it
is given and its defaults, and reads nothing else. :meth:`Settings.from_env` (the command
line's) reads every field with pydantic-settings, highest first: the environment
(``HIKOBOSHI_`` and the field's name in capitals, ``HIKOBOSHI_WORKER_QUEUE``; a few older
names too, :data:`ALIASES`), a ``.env`` file, and a secrets directory holding one file per
variable (container secrets, ``/run/secrets/HIKOBOSHI_TOKENS``). The token list, the
trusted proxies and the robot files keep their text formats (``token=name:role,...``,
comma-separated, ``os.pathsep``-separated). :func:`settings_table` is the table of
docs/operations.md "Settings" (``python -m server.settings`` writes it there).
"""

from __future__ import annotations

import argparse
import contextvars
import ipaddress
import os
import sys
from enum import StrEnum
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import AliasChoices, BaseModel, ConfigDict, Field, field_validator
from pydantic_settings import (
    BaseSettings,
    NoDecode,
    PydanticBaseSettingsSource,
    SettingsConfigDict,
)

__all__ = ["ALIASES", "ENV_PREFIX", "ApiToken", "Role", "Settings", "settings_table"]

ENV_PREFIX = "HIKOBOSHI_"

#: Variables read besides ``HIKOBOSHI_<FIELD>`` (names that worked before the prefix rule).
ALIASES: dict[str, tuple[str, ...]] = {
    "database_url": ("DATABASE_URL",),
    "robot_files": ("HIKOBOSHI_ROBOTS",),
}

#: ``.env`` file and secrets directory when the environment names none.
DEFAULT_ENV_FILE = Path(".env")
DEFAULT_SECRETS_DIR = Path("/run/secrets")

#: True only inside :meth:`Settings.from_env`: a ``Settings`` built directly reads nothing.
_reading_env: contextvars.ContextVar[bool] = contextvars.ContextVar(
    "hikoboshi_settings_from_env", default=False
)


def _env_alias(name: str) -> AliasChoices:
    return AliasChoices(name, ENV_PREFIX + name.upper(), *ALIASES.get(name, ()))


class Role(StrEnum):
    VIEWER = "viewer"  # read everything
    OPERATOR = "operator"  # viewer + plan and command
    SPACECRAFT = "spacecraft"  # the link endpoint only


class ApiToken(BaseModel):
    model_config = ConfigDict(frozen=True)
    name: str  # who holds it: written to the audit log
    role: Role


def parse_tokens(text: str) -> dict[str, ApiToken]:
    """``token=name:role,...`` as a token table; a clear ``ValueError`` for a bad item."""
    tokens: dict[str, ApiToken] = {}
    for item in filter(None, (part.strip() for part in text.split(","))):
        token, sep, holder = item.partition("=")
        name, _, role = holder.partition(":")
        if not sep or not token.strip() or not name.strip():
            raise ValueError("tokens are token=name:role,... (an item lacks its token or name)")
        try:
            tokens[token.strip()] = ApiToken(name=name.strip(), role=Role(role.strip()))
        except ValueError:
            roles = ", ".join(r.value for r in Role)
            raise ValueError(
                f"token of {name.strip()!r}: role {role.strip()!r} is not one of {roles}"
            ) from None
    return tokens


class Settings(BaseSettings):
    model_config = SettingsConfigDict(
        frozen=True,
        env_prefix=ENV_PREFIX,
        env_ignore_empty=True,  # HIKOBOSHI_TOKENS= (empty) is the default, as before
        extra="ignore",  # a .env shared with docker compose holds other variables
        validate_by_name=True,
        validate_by_alias=True,
        use_attribute_docstrings=True,
    )

    data_dir: Path = Path("data")
    """Where the SQLite database (without ``database_url``), the artifacts and the import
    spools live."""
    database_url: str | None = Field(default=None, validation_alias=_env_alias("database_url"))
    """The database: SQLite under ``data_dir`` unless a URL is given (``postgresql://...``)."""
    tokens: Annotated[dict[str, ApiToken], NoDecode] = Field(default_factory=dict)
    """The API tokens: token -> holder (written to the audit log) and role; in the
    environment ``token=name:role,...`` (roles viewer, operator, spacecraft)."""
    link_one_way_delay_s: float = 3.0
    """SPEC 6: the ground sends each command at least (one-way delay + margin) before its
    tag; the one-way delay (s)."""
    uplink_margin_s: float = 2.0
    """SPEC 6: the margin (s) added to the one-way delay (above)."""
    uplink_lead_window_s: float = Field(default=120.0, gt=0, le=3600)
    """The onboard schedule is kept loaded this far ahead of the onboard clock (onboard
    s): every command goes up this long before its tag, and is sent again until the
    vehicle acknowledges it, within the vehicle's announced schedule capacity. Longer than
    the outages a pass must ride through (SPEC 6)."""
    uplink_start_lead_s: float = Field(default=30.0, ge=0, le=600)
    """A pass's first command is tagged this long (onboard s) after the start, so that it
    too can be sent again before its tag if the relay loses it (the runner lengthens it at
    high time scales, so that the first command can go up three times)."""
    window_clock: Literal["ground", "vehicle"] = "ground"
    """Whose clock a pass's contact window (UTC) is judged on at its start: the ground's
    (``ground``), or the vehicle's onboard clock as the ground reads it (``vehicle``: a
    simulation flying a mission's day, whose onboard clock reads the mission's UTC, as
    ``hikoboshi spacecraft --mission`` does; the campaign demo). docs/missions.md."""
    command_period_s: float = 0.25
    """Onboard seconds between a plan's commands, as the runner tags them."""
    api_pool_size: int = Field(default=8, ge=1, le=100)
    """Connections of the readers' pool (REST routes, consoles) kept open. The command path
    (link, runner, abort) has its own pool of two and never waits behind readers."""
    api_pool_overflow: int = Field(default=4, ge=0, le=100)
    """Connections the readers' pool opens besides those when busy."""
    api_pool_timeout_s: float = Field(default=3.0, gt=0, le=60)
    """How long (s) a request waits for a reader's connection before 503 ``busy``."""
    api_statement_timeout_s: float = Field(default=30.0, gt=0, le=3600)
    """PostgreSQL: a reader's statement running longer than this is ended (503)."""
    viewer_requests_max: int = Field(default=16, ge=1, le=1000)
    """Capacity lanes (server/api/lanes.py, docs/security.md "Capacity"). Requests with a
    viewer's token running at once in the whole server: below the 40 threads synchronous
    routes and file streams share, so that viewers never hold every one an operator's
    request needs. Past it a request waits its turn (parked, no thread) while fewer than
    ``viewer_queue`` wait, at most ``viewer_queue_wait_s``; else 503 ``busy`` with
    ``Retry-After``."""
    viewer_queue: int = Field(default=256, ge=0, le=100_000)
    """Viewer requests that may wait their turn past ``viewer_requests_max``."""
    viewer_queue_wait_s: float = Field(default=10.0, ge=0, le=600)
    """How long (s) a viewer request waits its turn at most."""
    heavy_reads_per_token: int = Field(default=6, ge=1, le=100)
    """Heavy reads (a recording, the report, its page and figures, raw telemetry, an
    analyses run) in flight for one token holder; past it 429 ``too_many_requests``. Six:
    a browser's connections to one host, so that the console's report page, which loads
    its figures at once, is never refused its own figures."""
    operator_pool_size: int = Field(default=3, ge=1, le=50)
    """The operators' own connections (their requests and the consoles' hub): no viewer
    request uses them, so none can hold the one an operator or a console needs."""
    operator_pool_overflow: int = Field(default=2, ge=0, le=50)
    """Connections the operators' pool opens besides those when busy."""
    console_db_threads: int = Field(default=2, ge=1, le=32)
    """Threads the consoles' hub reads the database in (a subscription's check and replay
    of missed messages): its own, never the threads viewer requests share."""
    consoles_per_token: int = Field(default=8, ge=1, le=10_000)
    """Console websockets one token holder may hold at once (any role, any address), and
    viewers' consoles from one address; an operator's consoles count only against their
    own token's cap, so viewers cannot lock an operator out. Over a cap: closed 1013
    (docs/console.md "Connection caps", docs/security.md "Console caps")."""
    consoles_per_address: int = Field(default=16, ge=1, le=10_000)
    """Viewers' console websockets from one address at once (see above)."""
    max_import_bytes: int = 256 * 1024 * 1024
    """The largest MCAP recording ``POST /api/passes/import`` accepts (the 20-minute demo
    pass is 14 MB)."""
    max_plan_document_bytes: int = Field(default=32 * 1024 * 1024, gt=0)
    """The largest plan document ``POST /api/plans/documents`` accepts (a whole pass of the
    four experiments, ``hikoboshi plan pass``, is about 5 MB; a campaign's hour-long pass
    less than twice that)."""
    max_import_uncompressed_bytes: int = Field(default=2 * 1024**3, ge=1)
    """The most an imported recording's chunks may hold uncompressed, together (8 x the
    upload limit; recordings compress about 4:1), checked before anything is decompressed;
    one chunk may hold at most 64 MiB (docs/mcap.md)."""
    import_spool_budget_bytes: int = Field(default=2 * 256 * 1024 * 1024, ge=1)
    """The bytes the spool files of all imports in flight may hold on disk together (two
    uploads of the largest size): an import that would take them past it is refused, 503
    ``busy`` with ``Retry-After`` (docs/security.md "Import spools")."""
    worker_processes: int = Field(default=2, ge=1, le=64)
    """CPU-heavy requests (planning, recording downloads, reports, raw telemetry reads)
    run in worker processes (server/services/workers.py, docs/planning.md "Limits"): this
    many at once."""
    worker_queue: int = Field(default=8, ge=0, le=1000)
    """Jobs waiting for a worker process; past that 503 ``busy`` at once."""
    plan_deadline_s: float = Field(default=120.0, gt=0, le=3600)
    """A planning job is killed past this (s): 504. The worst plan the parameter bounds
    allow took 74 s on the 2-core reference machine under load (planner.catalogue)."""
    read_deadline_s: float = Field(default=120.0, gt=0, le=3600)
    """A heavy read (a recording, a report, raw telemetry) is killed past this (s): 504."""
    post_pass_deadline_s: float = Field(default=600.0, gt=0, le=7200)
    """Post-pass work (running a pass's analyses, importing a recording) is killed past
    this (s): 504. The 20-minute demo pass takes about 30 s of either on a loaded 2-core
    machine."""
    artifact_cache_bytes: int = Field(default=1024**3, ge=0)
    """Stored recordings, reports and figures (data_dir/artifacts, server/services/
    artifacts.py): at most this many bytes in all; past it the least recently served are
    deleted (0: nothing is kept, each version is still computed once per burst)."""
    worker_memory_bytes: int = Field(default=2 * 1024**3, ge=0)
    """The address space one job may use (bytes, RLIMIT_AS; 0: no limit): past it 503
    ``out_of_memory``."""
    max_request_bytes: int = Field(default=1024 * 1024, gt=0)
    """The HTTP edge (server/api/edge.py, docs/security.md). The largest request body any
    other route accepts: a larger declared Content-Length is refused (413) unread."""
    max_json_depth: int = Field(default=32, ge=1, le=1000)
    """The deepest nesting of arrays and objects a JSON body may have."""
    auth_failure_limit: int = Field(default=20, ge=1)
    """Failed authentications from one address within the window before that address is
    answered 429 for the rest of the window."""
    auth_failure_window_s: float = Field(default=60.0, gt=0)
    """The window (s) failed authentications are counted in."""
    auth_tracked_addresses: int = Field(default=10_000, ge=1)
    """How many addresses' failed authentications are tracked at most."""
    trusted_proxies: Annotated[tuple[str, ...], NoDecode] = ()
    """Peers whose ``X-Forwarded-For`` / ``X-Forwarded-Proto`` are believed (addresses or
    networks, ``10.0.0.0/8``; ``HIKOBOSHI_TRUSTED_PROXIES``, comma-separated): the reverse
    proxy in front of ``serve``. None by default: the client is the peer, whatever it
    claims (docs/security.md "Failed authentications")."""
    header_timeout_s: float = Field(default=10.0, gt=0)
    """``hikoboshi serve``: a connection whose request head has not fully arrived this
    long (s) after its first byte (or after it opened) is closed."""
    keep_alive_timeout_s: float = Field(default=5.0, gt=0)
    """``hikoboshi serve``: idle keep-alive connections are closed after this (s)."""
    max_header_bytes: int = Field(default=16 * 1024, ge=1024)
    """``hikoboshi serve``: a request head may be at most this large (bytes)."""
    robot_files: Annotated[tuple[Path, ...], NoDecode] = Field(
        default=(), validation_alias=_env_alias("robot_files")
    )
    """Robot descriptions the server plans for besides those shipped under
    ``examples/robots/`` (``hikoboshi serve --robot FILE``, ``HIKOBOSHI_ROBOTS``): a plan
    request names a robot, never a file (server/services/robots.py)."""
    missions_dir: Path | None = None
    """A folder of mission files (``NAME.toml``, docs/missions.md) the server knows
    besides those shipped under ``examples/missions/`` (``HIKOBOSHI_MISSIONS_DIR``): a
    windows or pass request names a mission, never a file (server/services/missions.py)."""
    limit_checking: bool = True
    """Check every archived frame and the link's health against the pass's limits and
    raise alarms (server/services/alarms.py, docs/alarms.md). Off: no limit alarms (the
    vehicle's safing alarm still comes); bench/bench_downlink.py measures the cost."""

    # --- malformed messages on the spacecraft link (server/services/malformed.py,
    # docs/protocol.md "Malformed messages") ---------------------------------------------
    malformed_interval_s: float = Field(default=5.0, gt=0, le=3600)
    """Malformed messages on the spacecraft link: one audit row per kind per interval
    (ground s); also how long a connection must carry nothing readable before it can be
    found unusable (``malformed_unusable_after``)."""
    malformed_replies_per_s: float = Field(default=10.0, ge=0, le=1000)
    """``error`` replies to malformed messages, at most this many a second."""
    malformed_unusable_after: int = Field(default=1000, ge=1)
    """More malformed messages than this in a row on one connection, and nothing readable on
    it for a whole ``malformed_interval_s``: its stream is unusable, the ground closes it
    (1008) and the vehicle reconnects. Malformed messages beside readable ones never close
    the link (they are dropped and counted)."""

    # --- command authority (server/services/authority.py, docs/operations.md "One ground
    # in command") -----------------------------------------------------------------------
    command_lease: str = Field(default="vehicle", min_length=1, max_length=64)
    """The name of the vehicle's command lease: the grounds that may command one vehicle
    share it, and exactly one of them holds it (the others are hot standbys)."""
    ground_name: str | None = Field(default=None, min_length=1, max_length=80)
    """This ground's name as a lease holder (the host's name when unset; the process id
    and a random suffix are added, so a restarted ground is a new holder)."""
    lease_ttl_s: float = Field(default=10.0, ge=1.0, le=600)
    """The command lease's time to live (wall s, on the database's clock): a standby takes
    over this long after the holder's last renewal, once the holder died; the holder stops
    sending ``lease_ttl_s - lease_renew_s`` after the start of its last renewal."""
    lease_renew_s: float = Field(default=1.0, gt=0, le=60)
    """The holder renews its lease, and a standby tries to take it, this often (wall s;
    under half of ``lease_ttl_s``)."""

    database_journal_max: int = Field(default=200_000, ge=100, le=10_000_000)
    """While the database does not answer, the command path keeps up to this many writes
    (stage moves, events, frame batches) in memory, in order, and replays them when it is
    back; past it a write is refused, logged and counted (docs/operations.md "A database
    outage")."""

    # --- consoles across grounds (server/services/jetstream.py, docs/console.md "Across
    # grounds") ----------------------------------------------------------------------------
    nats_url: str | None = Field(default=None, min_length=1, max_length=500)
    """A NATS server with JetStream (``nats://host:4222``; needs the ``hikoboshi[nats]``
    extra): every ground publishes its live events there and feeds its consoles from there,
    so a console sees the same live view on any ground and resumes on another. None: each
    ground serves its own consoles from its own process."""
    nats_stream: str = Field(default="HIKOBOSHI", pattern=r"^[A-Za-z0-9_-]{1,64}$")
    """The JetStream stream the grounds share (created by the first ground, with the limits
    below; its creation time names the consoles' ``epoch``)."""
    nats_max_age_s: float = Field(default=86400.0, gt=0)
    """The stream keeps a message this long (s) at most: a console resumes within it."""
    nats_max_bytes: int = Field(default=1024 * 1024 * 1024, ge=1024 * 1024)
    """The stream holds this many bytes at most; past them the oldest messages go (a
    console asking for them is told ``resync``)."""

    # --- the Foxglove live view (server/services/foxglove_live.py, docs/mcap.md) ---------
    foxglove_port: int | None = Field(default=None, ge=0, le=65535)
    """Stream the live pass to Foxglove on this port (foxglove-sdk's websocket server in the
    ground process; needs the ``hikoboshi[foxglove]`` extra; ``hikoboshi serve
    --foxglove-port``; 0: a free port). None: no live view."""
    foxglove_host: str = "127.0.0.1"
    """The address the Foxglove live view listens on; a viewer's token is asked there
    (``Authorization: Bearer`` or ``?token=``: server/api/foxglove_gate.py)."""

    @field_validator("tokens", mode="before")
    @classmethod
    def _tokens_from_text(cls, value: Any) -> Any:
        return parse_tokens(value) if isinstance(value, str) else value

    @field_validator("trusted_proxies", mode="before")
    @classmethod
    def _proxies_from_text(cls, value: Any) -> Any:
        if isinstance(value, str):
            return tuple(p.strip() for p in value.split(",") if p.strip())
        return value

    @field_validator("robot_files", mode="before")
    @classmethod
    def _robots_from_text(cls, value: Any) -> Any:
        if isinstance(value, str):
            return tuple(Path(p) for p in value.split(os.pathsep) if p.strip())
        return value

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
    def settings_customise_sources(
        cls,
        settings_cls: type[BaseSettings],
        init_settings: PydanticBaseSettingsSource,
        env_settings: PydanticBaseSettingsSource,
        dotenv_settings: PydanticBaseSettingsSource,
        file_secret_settings: PydanticBaseSettingsSource,
    ) -> tuple[PydanticBaseSettingsSource, ...]:
        if not _reading_env.get():
            return (init_settings,)
        return (init_settings, env_settings, dotenv_settings, file_secret_settings)

    @classmethod
    def from_env(cls, *, env_file: Path | None = None, secrets_dir: Path | None = None) -> Settings:
        """Every setting from the environment, then ``env_file`` (default
        ``HIKOBOSHI_ENV_FILE``, else ``./.env`` if there is one), then ``secrets_dir``
        (default ``HIKOBOSHI_SECRETS_DIR``, else ``/run/secrets`` if there is one): a file
        per variable, named as it (``HIKOBOSHI_TOKENS``). A bad value: ``ValueError``
        naming the variable."""
        if env_file is None:
            named = os.environ.get(ENV_PREFIX + "ENV_FILE")
            env_file = Path(named) if named else DEFAULT_ENV_FILE
        if secrets_dir is None:
            named = os.environ.get(ENV_PREFIX + "SECRETS_DIR")
            secrets_dir = Path(named) if named else DEFAULT_SECRETS_DIR
        for path, var in ((env_file, "ENV_FILE"), (secrets_dir, "SECRETS_DIR")):
            if os.environ.get(ENV_PREFIX + var) and not path.exists():
                raise ValueError(f"{ENV_PREFIX}{var}: {path} does not exist")
        token = _reading_env.set(True)
        try:
            return cls(  # type: ignore[call-arg]  # pydantic-settings init options
                _env_file=env_file if env_file.is_file() else None,
                _secrets_dir=secrets_dir if secrets_dir.is_dir() else None,
            )
        finally:
            _reading_env.reset(token)


def env_names(name: str) -> tuple[str, ...]:
    """The variables (and secret files) ``Settings.from_env`` reads ``name`` from."""
    return (ENV_PREFIX + name.upper(), *ALIASES.get(name, ()))


def _default_text(name: str) -> str:
    field = Settings.model_fields[name]
    value = field.get_default(call_default_factory=True)
    if value is None or value in ({}, ()):
        return "none"
    if isinstance(value, bool):
        return "on" if value else "off"
    if isinstance(value, int) and value >= 1024 * 1024 and value % (1024 * 1024) == 0:
        return f"{value} ({value // (1024 * 1024)} MiB)"
    return str(value)


def settings_table() -> str:
    """docs/operations.md "Settings": one row per field of :class:`Settings`, its
    variables, its default and its meaning (the field's docstring)."""
    rows = [
        "| Setting | Variable | Default | Meaning |",
        "| --- | --- | --- | --- |",
    ]
    for name, field in Settings.model_fields.items():
        meaning = " ".join((field.description or "").split()).replace("|", "\\|").replace("``", "`")
        variables = ", ".join(f"`{v}`" for v in env_names(name))
        rows.append(f"| `{name}` | {variables} | {_default_text(name)} | {meaning} |")
    return "\n".join(rows) + "\n"


DOCS = Path(__file__).resolve().parent.parent / "docs" / "operations.md"
_BEGIN = "<!-- settings table: python -m server.settings writes it -->"
_END = "<!-- end of settings table -->"


def docs_with_table(text: str) -> str:
    """``text`` (docs/operations.md) with the settings table between its markers."""
    start, end = text.index(_BEGIN) + len(_BEGIN), text.index(_END)
    return text[:start] + "\n" + settings_table() + text[end:]


def main(argv: list[str] | None = None) -> int:
    """``python -m server.settings``: write the table into docs/operations.md; ``--check``
    exits 1 when the committed table differs."""
    parser = argparse.ArgumentParser(prog="python -m server.settings")
    parser.add_argument("--check", action="store_true")
    args = parser.parse_args(argv)
    text = DOCS.read_text()
    wanted = docs_with_table(text)
    if args.check:
        if wanted != text:
            print(f"{DOCS} is out of date: run python -m server.settings", file=sys.stderr)
            return 1
        return 0
    DOCS.write_text(wanted)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
