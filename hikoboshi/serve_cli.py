"""``hikoboshi serve``: the ground service (:mod:`server.app`) under uvicorn, its settings
from the environment and the options, refused with one line when they cannot serve safely
(no tokens off loopback, a bad robot description)."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Annotated

import typer

from hikoboshi.cli_common import (
    FoxglovePortOption,
    LogFormatOption,
    LogLevelOption,
    _check_foxglove,
    _configure_logging,
    _fail,
    _load,
)

__all__ = ["register"]


def _is_loopback(host: str) -> bool:
    import ipaddress

    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def serve(
    host: Annotated[str, typer.Option(help="Address to listen on")] = "127.0.0.1",
    port: Annotated[int, typer.Option(help="Port to listen on")] = 8000,
    robot: Annotated[
        list[Path] | None,
        typer.Option(
            "--robot",
            help="A robot description (TOML) the server may plan for, besides those shipped "
            "under examples/robots/; plan requests name it by its name. Repeatable.",
        ),
    ] = None,
    log_format: LogFormatOption = "text",
    log_level: LogLevelOption = "info",
    foxglove_port: FoxglovePortOption = None,
) -> None:
    """Run the ground service. Settings from the environment: DATABASE_URL (default SQLite
    under HIKOBOSHI_DATA_DIR, ./data), HIKOBOSHI_TOKENS (token=name:role,...; required
    unless listening on loopback only), HIKOBOSHI_ROBOTS (description files, as --robot),
    HIKOBOSHI_TRUSTED_PROXIES (the reverse proxy's addresses or networks, comma-separated:
    X-Forwarded-For is believed from them only; none by default). The HTTP edge's limits
    and timeouts are in docs/security.md."""
    from server.api.http_server import uvicorn_config
    from server.app import GroundServer, create_app
    from server.redaction import install_redaction
    from server.settings import Settings

    install_redaction()  # before anything logs (uvicorn_config installs it too)
    _configure_logging(log_format, log_level)
    startup_log = logging.getLogger("hikoboshi.ground.settings")

    try:
        settings = Settings.from_env()
    except ValueError as exc:
        _fail(f"bad settings in the environment: {exc}")
    if robot:
        settings = settings.model_copy(
            update={"robot_files": (*settings.robot_files, *(p.resolve() for p in robot))}
        )
    if foxglove_port is not None:
        settings = settings.model_copy(update={"foxglove_port": foxglove_port})
    if settings.foxglove_port is not None:
        _check_foxglove(settings.foxglove_port)
    for path in settings.robot_files:
        _load(path)  # one clear error line for a bad description, before serving
    if not settings.tokens:
        if not _is_loopback(host):
            _fail(
                f"HIKOBOSHI_TOKENS is empty and --host {host} is not loopback: refusing to "
                "serve a network with no tokens. Set HIKOBOSHI_TOKENS=token=name:role,... "
                '(strong tokens: python -c "import secrets; print(secrets.token_urlsafe(32))")'
            )
        # through the log (its format: a JSON collector reads every line), not a bare print
        startup_log.warning("HIKOBOSHI_TOKENS is empty: every API call will be refused")
    weak = sorted({t.name for secret, t in settings.tokens.items() if len(secret) < 16})
    if weak:
        startup_log.warning(
            "short (guessable) tokens for %s",
            ", ".join(weak),
            extra={"fields": {"event": "weak_tokens", "names": weak}},
        )
    ground = create_app(settings)
    config = uvicorn_config(ground, settings, host=host, port=port, log_level=log_level.lower())
    # On SIGTERM it stops the worker pool first: requests waiting answer JSON 503
    # shutting_down and no job process outlives it (docs/operations.md "Stopping").
    GroundServer(config, ground).run()


def register(app: typer.Typer) -> None:
    """Add ``serve`` to ``hikoboshi``."""
    app.command("serve")(serve)
