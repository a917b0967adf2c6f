"""No secret in any log (server/redaction.py, docs/security.md "Logs"): the redaction of
the records uvicorn, websockets, httpx and our own loggers write, and its installation in
front of every logger of a process, a real server's included."""

from __future__ import annotations

import asyncio
import io
import logging
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
import uvicorn

from server.api.http_server import uvicorn_config
from server.app import create_app
from server.redaction import RedactSecretsFilter, install_redaction, redact, redact_record
from server.settings import ApiToken, Role, Settings
from tests.support.processes import free_port

SECRET = "s3cret-Tok_en.value"


def _record(name: str, msg: str, *args: object) -> logging.LogRecord:
    return logging.LogRecord(name, logging.INFO, __file__, 1, msg, args, None)


@pytest.mark.parametrize(
    ("name", "msg", "args"),
    [
        # uvicorn.error's websocket accept line (uvicorn/protocols/websockets/*_impl.py)
        (
            "uvicorn.error",
            '%s - "WebSocket %s" [accepted]',
            ("127.0.0.1:5555", f"/api/link?token={SECRET}"),
        ),
        ("uvicorn.error", '%s - "WebSocket %s" 403', ("127.0.0.1:5555", f"/x?a=1&token={SECRET}")),
        # uvicorn.access
        (
            "uvicorn.access",
            '%s - "%s %s HTTP/%s" %d',
            ("127.0.0.1:5000", "GET", f"/api/x?a=1&access_token={SECRET}&b=2", "1.1", 200),
        ),
        # websockets' client handshake at debug: a header line
        ("websockets.client", "> %s: %s", ("Authorization", f"Bearer {SECRET}")),
        ("websockets.client", "> GET %s HTTP/1.1", (f"/api/link?api_key={SECRET}",)),
        # httpx: the URL is an object, not a str
        (
            "httpx",
            'HTTP Request: %s %s "%s %d %s"',
            ("GET", httpx.URL(f"http://h/api?token={SECRET}"), "HTTP/1.1", 200, "OK"),
        ),
        # our own: a URL, a header mapping's repr, a command line
        ("hikoboshi.spacecraft", "connected to %s", (f"ws://h/api/link?token={SECRET}",)),
        ("hikoboshi.ground.edge", "headers %r", ({"authorization": f"Bearer {SECRET}"},)),
        ("hikoboshi.ground.edge", "headers %r", ([(b"authorization", SECRET.encode())],)),
        ("hikoboshi.x", "running %s", (f"hikoboshi spacecraft --token {SECRET} --seed 1",)),
        ("hikoboshi.x", f"Authorization: Basic {SECRET}", ()),
    ],
    ids=[
        "uvicorn-ws-accept",
        "uvicorn-ws-403",
        "uvicorn-access",
        "websockets-header",
        "websockets-path",
        "httpx-url-object",
        "our-url",
        "our-header-dict",
        "our-header-pairs",
        "command-line",
        "basic",
    ],
)
def test_every_kind_of_record_is_redacted(name: str, msg: str, args: tuple[object, ...]) -> None:
    record = _record(name, msg, *args)
    assert SECRET in record.getMessage()  # the test's record does hold the secret
    assert RedactSecretsFilter().filter(record)
    line = record.getMessage()
    assert SECRET not in line and "[redacted]" in line, line


def test_what_is_not_a_secret_is_kept() -> None:
    for text in (
        "authentication failed: reason='an API token is required (Authorization: Bearer)'",
        "GET /api/passes?limit=10&offset=20 HTTP/1.1",
        "basic checks passed; bearer of news",
        "the token file is out/demo/tokens",
    ):
        assert redact(text) == text
    assert redact("GET /a?token=x&b=2") == "GET /a?token=[redacted]&b=2"


def test_a_traceback_is_redacted() -> None:
    try:
        raise ConnectionError(f"cannot open ws://h/api/link?token={SECRET}")
    except ConnectionError:
        record = logging.LogRecord(
            "websockets.client", logging.ERROR, __file__, 1, "failed", (), sys.exc_info()
        )
    redact_record(record)
    text = logging.Formatter().format(record)
    assert "ConnectionError" in text and SECRET not in text


@pytest.fixture()
def redacting() -> Iterator[None]:
    """The process's record factory wrapped for the test, as it was afterwards."""
    factory = logging.getLogRecordFactory()
    install_redaction()
    install_redaction()  # idempotent: wrapped once
    try:
        yield
    finally:
        logging.setLogRecordFactory(factory)


def _capture(name: str) -> tuple[logging.Logger, io.StringIO, logging.Handler]:
    stream = io.StringIO()
    handler = logging.StreamHandler(stream)
    logger = logging.getLogger(name)
    logger.addHandler(handler)
    return logger, stream, handler


def test_installed_it_redacts_every_logger_and_handler(redacting: None) -> None:
    """A handler added after the installation, on a logger no one configured, gets
    redacted records: the redaction is where records are made."""
    for name in ("uvicorn.error", "websockets.client", "httpx", "hikoboshi.anything", "x.y"):
        logger, stream, handler = _capture(name)
        level = logger.level
        logger.setLevel(logging.DEBUG)
        try:
            logger.debug('%s - "WebSocket %s" [accepted]', "h:1", f"/api/link?token={SECRET}")
            logger.debug("> Authorization: Bearer %s", SECRET)
        finally:
            logger.removeHandler(handler)
            logger.setLevel(level)
        text = stream.getvalue()
        assert text.count("[redacted]") == 2 and SECRET not in text, (name, text)


def test_a_real_servers_accept_line_is_redacted(tmp_path: Path) -> None:
    """A websocket to a real server (as ``serve`` runs it, logging at info) with a token in
    its URL: uvicorn.error writes the accept line, the route refuses it (tokens in URLs are
    not accepted), and the line has no token."""
    import websockets

    token = "s-" + SECRET
    settings = Settings(
        data_dir=tmp_path, tokens={token: ApiToken(name="sc", role=Role.SPACECRAFT)}
    )
    factory = logging.getLogRecordFactory()
    port = free_port()
    config = uvicorn_config(create_app(settings), settings, host="127.0.0.1", port=port)
    logger, stream, handler = _capture("uvicorn.error")
    server = uvicorn.Server(config)
    thread = threading.Thread(target=server.run, name="uvicorn-redaction", daemon=True)
    thread.start()
    try:
        deadline = time.monotonic() + 30.0  # a guard, not a timing assertion
        while not server.started:
            assert thread.is_alive() and time.monotonic() < deadline, "uvicorn did not start"
            time.sleep(0.01)

        async def connect() -> int | None:
            url = f"ws://127.0.0.1:{port}/api/link?token={token}"
            async with websockets.connect(url) as ws:
                with pytest.raises(websockets.ConnectionClosed) as closed:
                    await ws.recv()
            return None if closed.value.rcvd is None else closed.value.rcvd.code

        assert asyncio.run(connect()) == 1008
    finally:
        server.should_exit = True
        thread.join(timeout=30.0)
        logger.removeHandler(handler)
        logging.setLogRecordFactory(factory)
    text = stream.getvalue()
    assert '"WebSocket /api/link?token=[redacted]" [accepted]' in text, text
    assert SECRET not in text


@pytest.mark.parametrize(
    ("args", "env"),
    [
        (["serve", "--host", "0.0.0.0"], {"HIKOBOSHI_TOKENS": ""}),  # refused: no tokens
        (
            [
                "spacecraft",
                "--ground",
                "ws://127.0.0.1:1/api/link",
                "--token",
                SECRET,
                "--outage",
                "70:40",
            ],
            {},
        ),
        (["demo", "--speed", "0"], {}),  # refused: a bad option
    ],
    ids=["serve", "spacecraft", "demo"],
)
def test_the_command_line_installs_it_before_anything_logs(
    args: list[str], env: dict[str, str], tmp_path: Path
) -> None:
    """``serve``, ``spacecraft`` and ``demo`` install the redaction first: even a run that
    stops at its first check leaves the process's records redacted."""
    from typer.testing import CliRunner

    from hikoboshi.cli import app
    from server import redaction

    factory = logging.getLogRecordFactory()
    logging.setLogRecordFactory(logging.LogRecord)  # as a fresh process has it
    try:
        env = {"HIKOBOSHI_DATA_DIR": str(tmp_path), "DATABASE_URL": "", **env}
        result = CliRunner().invoke(app, args, env=env)
        assert result.exit_code == 2, result.output  # stopped at its first check
        installed = logging.getLogRecordFactory()
        assert installed is not logging.LogRecord and installed is redaction._installed
        record = installed("x", logging.INFO, __file__, 1, "--token %s", (SECRET,), None)
        assert SECRET not in record.getMessage()
    finally:
        logging.setLogRecordFactory(factory)
