"""The HTTP edge (server/api/edge.py, docs/security.md): authentication before any body is
read, the size and depth limits, text the databases refuse, the failed-authentication
limit, the security headers, constant-time tokens, and how ``serve`` runs uvicorn."""

from __future__ import annotations

import asyncio
import hmac
import inspect
import json
import logging
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import uvicorn
from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy.exc import DataError
from starlette.types import Message, Receive, Scope, Send
from starlette.websockets import WebSocketDisconnect
from typer.testing import CliRunner

from server.api import deps
from server.api.edge import AuthGuard, RedactSecretsFilter, check_json, uvicorn_config
from server.app import create_app
from server.settings import ApiToken, Role, Settings
from server.storage import repository as repo
from tests.server.api.conftest import OPERATOR, TOKENS, VIEWER, add_pass, sessions
from tests.server.storage.factories import make_plan

MIB = 1024 * 1024
JSON = {"Content-Type": "application/json"}


def _error(response: Any) -> str:
    assert response.headers["content-type"] == "application/json", response.text
    code: str = response.json()["error"]["code"]
    return code


def _nothing_stored(client: TestClient) -> None:
    with sessions(client)() as session:
        assert repo.list_passes(session=session).count == 0
        assert repo.list_events(session=session).count == 0


# --- the ASGI application called directly: what it reads of a body -----------------------


class Call:
    """One HTTP request straight into the ASGI application, counting the body bytes the
    application pulled."""

    def __init__(self, chunks: list[bytes]) -> None:
        self.chunks = list(chunks)
        self.read = 0
        self.status = 0
        self.headers: dict[str, str] = {}
        self.body = b""

    async def receive(self) -> Message:
        if not self.chunks:
            await asyncio.sleep(3600)  # a client that sends no more (until cancelled)
        chunk = self.chunks.pop(0)
        self.read += len(chunk)
        return {"type": "http.request", "body": chunk, "more_body": bool(self.chunks)}

    async def send(self, message: Message) -> None:
        if message["type"] == "http.response.start":
            self.status = message["status"]
            self.headers = {k.decode(): v.decode() for k, v in message["headers"]}
        elif message["type"] == "http.response.body":
            self.body += message.get("body", b"")

    def run(self, app: Any, method: str, path: str, headers: dict[str, str]) -> Call:
        scope: Scope = {
            "type": "http",
            "asgi": {"version": "3.0"},
            "http_version": "1.1",
            "method": method,
            "scheme": "http",
            "path": path,
            "raw_path": path.encode(),
            "root_path": "",
            "query_string": b"",
            "headers": [(k.lower().encode(), v.encode()) for k, v in headers.items()],
            "client": ("192.0.2.9", 4711),
            "server": ("testserver", 80),
            "state": {},
        }
        asyncio.run(asyncio.wait_for(app(scope, self.receive, self.send), timeout=30))
        return self

    @property
    def code(self) -> str:
        code: str = json.loads(self.body)["error"]["code"]
        return code


def test_an_anonymous_30_mb_body_is_refused_before_a_byte_is_read(client: TestClient) -> None:
    chunks = [b"[" * 65536] * 480  # 30 MiB, offered 64 KiB at a time
    headers = {"content-type": "application/json", "content-length": str(30 * MIB)}
    call = Call(chunks).run(client.app, "POST", "/api/passes", headers)
    assert (call.status, call.code, call.read) == (401, "unauthorized", 0)
    assert call.headers["connection"] == "close"  # the rest is never read


def test_a_declared_body_over_the_limit_is_refused_unread(client: TestClient) -> None:
    headers = {**OPERATOR, "content-type": "application/json", "content-length": str(2 * MIB)}
    call = Call([b"{}"]).run(client.app, "POST", "/api/passes", headers)
    assert (call.status, call.code, call.read) == (413, "request_too_large", 0)


def test_a_streamed_body_is_cut_off_past_the_limit(client: TestClient) -> None:
    chunks = [b" " * 256 * 1024] * 16  # 4 MiB, no content-length
    headers = {**OPERATOR, "content-type": "application/json", "transfer-encoding": "chunked"}
    call = Call(chunks).run(client.app, "POST", "/api/passes", headers)
    assert (call.status, call.code) == (413, "request_too_large")
    assert MIB < call.read <= MIB + 256 * 1024


def test_the_import_streams_past_the_request_limit_to_its_own(client: TestClient) -> None:
    body = b"\x89MCAP0\r\n" + b"\0" * (2 * MIB)  # over 1 MiB, under max_import_bytes
    headers = {**OPERATOR, "Content-Type": "application/octet-stream"}
    response = client.post("/api/passes/import", content=body, headers=headers)
    assert 400 <= response.status_code < 500 and response.status_code != 413, response.text
    assert _error(response) != "request_too_large"  # refused by the reader, not the edge
    anonymous = client.post("/api/passes/import", content=body)
    assert (anonymous.status_code, _error(anonymous)) == (401, "unauthorized")


def test_an_over_limit_json_body_with_a_token_is_413(client: TestClient) -> None:
    body = b'{"name": "' + b"x" * MIB + b'"}'
    response = client.post("/api/passes", content=body, headers={**OPERATOR, **JSON})
    assert (response.status_code, _error(response)) == (413, "request_too_large")
    _nothing_stored(client)


# --- JSON bodies ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("body", "code"),
    [
        ("[" * 10_000 + "]" * 10_000, "json_too_deep"),  # the parser's RecursionError
        ('{"a":' * 33 + "1" + "}" * 33, "json_too_deep"),  # parsed, then counted
        ('{"plan_id": "p", "name": [' + "[" * 40 + "]" * 40 + "]}", "json_too_deep"),
        ("{not json", "invalid_json"),
        ('{"name": "\\u0000"}', "invalid_text"),
        ('{"name": "bell \\u0007"}', "invalid_text"),
        ('{"name": "del \\u007f"}', "invalid_text"),
        ('{"name": "lone \\ud800"}', "invalid_text"),
        ('{"na\\u0000me": "key"}', "invalid_text"),
        ('[{"deep": ["ok", "esc \\u001b[31m"]}]', "invalid_text"),
    ],
    ids=[
        "10k-brackets",
        "33-objects",
        "41-in-a-field",
        "not-json",
        "nul",
        "bel",
        "del",
        "surrogate",
        "nul-in-key",
        "esc-nested",
    ],
)
def test_json_bodies_are_checked_before_the_route(client: TestClient, body: str, code: str) -> None:
    response = client.post("/api/passes", content=body.encode(), headers={**OPERATOR, **JSON})
    assert (response.status_code, _error(response)) == (400, code), response.text
    assert response.json()["error"]["message"]
    _nothing_stored(client)


def test_a_body_without_a_content_type_is_checked_as_json(client: TestClient) -> None:
    # FastAPI reads a body without a content type as JSON: so does the edge.
    response = client.post("/api/passes", content=b'{"name": "\\u0000"}', headers=OPERATOR)
    assert (response.status_code, _error(response)) == (400, "invalid_text")


def test_check_json_limits() -> None:
    assert check_json(b'{"a": "tab\\t newline\\n return\\r"}', 32) is None
    assert check_json(b"[" * 32 + b"]" * 32, 32) is None
    refused = check_json(b"[" * 33 + b"]" * 33, 32)
    assert refused is not None and refused[0] == "json_too_deep"
    refused = check_json(b'{"a": [1, {"b": "x\\u0000"}]}', 32)
    assert refused is not None and refused[0] == "invalid_text"
    assert refused[2] == {"loc": ["a", 1, "b"], "char": "U+0000"}
    assert "at .a[1].b" in refused[1]


def test_a_deep_but_allowed_body_reaches_the_route(client: TestClient) -> None:
    body = {"plan_id": "p", "name": [[[[1]]]]}
    response = client.post("/api/passes", json=body, headers=OPERATOR)
    assert (response.status_code, _error(response)) == (422, "invalid_request")


# --- text the databases refuse, on SQLite and PostgreSQL ------------------------------------


def test_nul_in_a_pass_name_is_refused_and_nothing_stored(client: TestClient) -> None:
    with sessions(client)() as session:
        plan_id = repo.add_plan(session=session, plan=make_plan(), created_at_ns=0).id
        session.commit()
    body = {
        "plan_id": plan_id,
        "name": "pass\x00one",
        "aos_time": "2031-03-04T05:06:07Z",
        "los_time": "2031-03-04T06:06:07Z",
    }
    response = client.post("/api/passes", json=body, headers=OPERATOR)
    assert (response.status_code, _error(response)) == (400, "invalid_text")
    _nothing_stored(client)


@pytest.mark.parametrize("action", ["start", "abort"])
def test_nul_in_a_confirmation_is_refused_and_nothing_stored(
    client: TestClient, action: str
) -> None:
    pass_id = add_pass(client, "pass-7")
    body = {"confirm": f"{action.upper()} pass-7\x00", "reason": "r"}
    response = client.post(f"/api/passes/{pass_id}/{action}", json=body, headers=OPERATOR)
    assert (response.status_code, _error(response)) == (400, "invalid_text")
    with sessions(client)() as session:
        assert repo.get_pass(session=session, pass_id=pass_id).state == "scheduled"
        assert repo.list_events(session=session).count == 0


@pytest.mark.parametrize(
    ("path", "headers"),
    [
        ("/api/plans?experiment=%00", VIEWER),
        ("/api/plans?experiment=a%7Fb", VIEWER),
        ("/api/passes?state=%1b", VIEWER),
        ("/api/passes/%00", VIEWER),
        ("/api/passes/a%0Ab", {}),
        ("/assets/a%00.js", {}),
        ("/model/x%00.urdf", {}),
        ("/%00", {}),
    ],
)
def test_control_characters_in_paths_and_queries_are_refused(
    client: TestClient, path: str, headers: dict[str, str]
) -> None:
    response = client.get(path, headers=headers)
    assert (response.status_code, _error(response)) == (400, "invalid_text")
    assert response.headers["x-content-type-options"] == "nosniff"


def test_ordinary_queries_still_pass(client: TestClient) -> None:
    response = client.get("/api/plans?experiment=ptp%20x&limit=5", headers=VIEWER)
    assert response.status_code == 200, response.text


# --- errors in the shape --------------------------------------------------------------------


@pytest.fixture()
def probed(tmp_path: Path) -> Iterator[TestClient]:
    """An application with routes that fail: a DataError and an unexpected exception."""
    app = create_app(Settings(data_dir=tmp_path, tokens=TOKENS))

    @app.get("/api/_probe/data-error")
    async def data_error(_: deps.ViewerDep) -> None:
        raise DataError("INSERT ...", {}, ValueError("text fields cannot contain NUL"))

    @app.get("/api/_probe/boom")
    async def boom(_: deps.ViewerDep) -> None:
        raise RuntimeError("secret internals")

    with TestClient(app, raise_server_exceptions=False) as c:
        yield c


def test_a_database_data_error_is_400_in_the_shape(probed: TestClient) -> None:
    response = probed.get("/api/_probe/data-error", headers=VIEWER)
    assert (response.status_code, _error(response)) == (400, "invalid_data")
    assert "INSERT" not in response.text


def test_an_unexpected_error_is_500_in_the_shape(
    probed: TestClient, caplog: pytest.LogCaptureFixture
) -> None:
    with caplog.at_level(logging.ERROR, logger="hikoboshi.ground.errors"):
        response = probed.get("/api/_probe/boom", headers=VIEWER)
    assert (response.status_code, _error(response)) == (500, "internal_error")
    assert "secret internals" not in response.text and "Traceback" not in response.text
    assert any(r.exc_info and "secret internals" in str(r.exc_info[1]) for r in caplog.records)


# --- failed authentication: audit and limit -------------------------------------------------


class _Address:
    """Puts the ``x-test-client`` header's address in the scope (the test client has one)."""

    def __init__(self, app: FastAPI) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] in ("http", "websocket"):
            headers = dict(scope["headers"])
            address = headers.get(b"x-test-client", b"203.0.113.1").decode()
            scope = {**scope, "client": (address, 5555)}
        await self.app(scope, receive, send)


@pytest.fixture()
def limited(tmp_path: Path) -> Iterator[tuple[TestClient, list[float]]]:
    """An application allowing 3 failures a minute, and its guard's clock (settable)."""
    settings = Settings(
        data_dir=tmp_path, tokens=TOKENS, auth_failure_limit=3, auth_failure_window_s=60.0
    )
    app = create_app(settings)
    now = [1000.0]
    app.state.auth_guard.clock = lambda: now[0]
    with TestClient(_Address(app)) as c:
        yield c, now


def test_failed_authentication_is_audited_and_limited_per_address(
    limited: tuple[TestClient, list[float]], caplog: pytest.LogCaptureFixture
) -> None:
    client, now = limited
    attacker = {"x-test-client": "198.51.100.7"}
    with caplog.at_level(logging.WARNING, logger="hikoboshi.audit"):
        for token in ("wrong-secret-1", "wrong-secret-2"):
            response = client.get("/api/passes", headers={**attacker, "Authorization": token})
            assert response.status_code == 401
        response = client.get(
            "/api/passes", headers={**attacker, "Authorization": "Bearer wrong-secret-3"}
        )
        assert (response.status_code, response.headers["www-authenticate"]) == (401, "Bearer")
        # The limit is reached: everything from there is 429, a good token too, and first.
        for path in ("/api/passes", "/api/health", "/assets/a%00.js"):
            response = client.get(path, headers={**attacker, **VIEWER})
            assert (response.status_code, _error(response)) == (429, "too_many_failures")
            assert response.headers["retry-after"] == "60"
    audited = [r.getMessage() for r in caplog.records if r.name == "hikoboshi.audit"]
    assert len(audited) == 4  # three failures, one "refused"
    assert all("198.51.100.7" in line for line in audited)
    assert "path='/api/passes'" in audited[0] and "an API token is required" in audited[0]
    assert "unknown API token" in audited[2]
    assert not any("wrong-secret" in line for line in audited)

    # Another address is not affected.
    other = {"x-test-client": "198.51.100.8", **VIEWER}
    assert client.get("/api/passes", headers=other).status_code == 200
    # The window runs out.
    now[0] += 30.0
    response = client.get("/api/passes", headers={**attacker, **VIEWER})
    assert (response.status_code, response.headers["retry-after"]) == (429, "30")
    now[0] += 30.0
    assert client.get("/api/passes", headers={**attacker, **VIEWER}).status_code == 200


def test_a_blocked_address_is_one_event_in_the_audit_log(
    limited: tuple[TestClient, list[float]],
) -> None:
    """The events table (what consoles and ``GET /api/events`` show) gets one
    ``auth_blocked`` per blocked window and address, however many failures follow."""
    client, now = limited
    attacker = {"x-test-client": "198.51.100.20", "Authorization": "Bearer nope"}
    for _ in range(10):
        client.get("/api/passes", headers=attacker)

    factory = client.app.app.state.sessions  # type: ignore[attr-defined]  # inside _Address

    def blocked() -> list[Any]:
        with factory() as session:
            return list(repo.list_events(session=session, kinds=["auth_blocked"]).items)

    deadline = time.monotonic() + 30.0
    while not blocked():  # written in a thread after the response
        assert time.monotonic() < deadline, "no auth_blocked event"
        time.sleep(0.05)
    [event] = blocked()
    assert event.actor == "edge" and event.pass_id is None
    assert event.detail == {"address": "198.51.100.20", "failures": 3, "blocked_s": 60.0}
    now[0] += 61.0  # a new window, blocked again: a second event
    for _ in range(3):
        client.get("/api/passes", headers=attacker)
    deadline = time.monotonic() + 30.0
    while len(blocked()) < 2:
        assert time.monotonic() < deadline, "no second auth_blocked event"
        time.sleep(0.05)
    time.sleep(0.2)
    assert len(blocked()) == 2


def test_websocket_failures_count_too(limited: tuple[TestClient, list[float]]) -> None:
    client, _ = limited
    bad = {"x-test-client": "198.51.100.9", "Authorization": "Bearer nope"}
    for path in ("/api/link", "/api/console", "/api/link"):
        with client.websocket_connect(path, headers=bad) as ws, pytest.raises(WebSocketDisconnect):
            ws.receive_text()
    # Refused at the handshake from now on, whatever the token.
    good = {"x-test-client": "198.51.100.9", **VIEWER}
    with pytest.raises(WebSocketDisconnect), client.websocket_connect("/api/console", headers=good):
        pass
    assert client.get("/api/passes", headers=good).status_code == 429


def test_the_guard_tracks_a_bounded_number_of_addresses() -> None:
    now = [0.0]
    guard = AuthGuard(limit=2, window_s=10.0, max_addresses=3, clock=lambda: now[0])
    for i in range(5):
        guard.failed(f"10.0.0.{i}", "/api/x", "unknown API token")
        now[0] += 1.0
    assert len(guard) == 3  # the oldest two went
    guard.failed("10.0.0.4", "/api/x", "unknown API token")
    assert guard.retry_after("10.0.0.4") == 9  # its window started at 4 s, it is 5 s now
    now[0] = 100.0
    assert guard.retry_after("10.0.0.4") is None and len(guard) == 0


# --- tokens ---------------------------------------------------------------------------------


def test_tokens_are_compared_in_constant_time(monkeypatch: pytest.MonkeyPatch) -> None:
    tokens = {f"token-{i}": ApiToken(name=f"n{i}", role=Role.VIEWER) for i in range(5)}
    calls: list[tuple[bytes, bytes]] = []
    real = hmac.compare_digest

    def counting(a: bytes, b: bytes) -> bool:
        calls.append((a, b))
        return bool(real(a, b))

    monkeypatch.setattr(hmac, "compare_digest", counting)  # as server.api.deps calls it
    found = deps.find_token(tokens, "token-0")
    assert found is not None and found.name == "n0"
    assert len(calls) == 5  # every token, no early exit
    assert all(len(a) == len(b) == 32 for a, b in calls)  # digests: equal lengths
    assert deps.find_token(tokens, "token-") is None
    assert deps.find_token(tokens, "token-00") is None
    assert deps.find_token({}, "") is None


def test_the_auth_dependencies_run_on_the_event_loop() -> None:
    for role in Role:
        assert inspect.iscoroutinefunction(deps.require(role))
    assert inspect.iscoroutinefunction(deps.get_settings)


def test_a_token_in_the_query_string_is_not_accepted(client: TestClient) -> None:
    for path in ("/api/link?token=s-token", "/api/passes?token=v-token"):
        if path.startswith("/api/link"):
            with client.websocket_connect(path) as ws, pytest.raises(WebSocketDisconnect) as closed:
                ws.receive_text()
            assert closed.value.code == 1008
        else:
            assert client.get(path).status_code == 401


def test_the_access_log_redacts_tokens_in_query_strings() -> None:
    record = logging.LogRecord(
        "uvicorn.access",
        logging.INFO,
        __file__,
        1,
        '%s - "%s %s HTTP/%s" %d',
        ("127.0.0.1:5000", "GET", "/api/x?a=1&token=s3cret&b=2", "1.1", 200),
        None,
    )
    assert RedactSecretsFilter().filter(record)
    line = record.getMessage()
    assert "s3cret" not in line and "token=[redacted]&b=2" in line


# --- headers --------------------------------------------------------------------------------


def test_security_headers(client: TestClient) -> None:
    page = client.get("/")
    assert page.status_code in (200, 503)  # the console, or the page saying to build it
    csp = page.headers["content-security-policy"]
    assert "frame-ancestors 'none'" in csp and "script-src 'self'" in csp
    assert "connect-src 'self' ws://testserver wss://testserver" in csp
    assert page.headers["x-frame-options"] == "DENY"
    for response in (
        page,
        client.get("/api/health"),
        client.get("/api/passes", headers=VIEWER),
        client.get("/api/passes"),
    ):
        assert response.headers["x-content-type-options"] == "nosniff"
        assert response.headers["referrer-policy"] == "no-referrer"
    assert "content-security-policy" not in client.get("/api/health").headers


# --- serving: a real uvicorn on loopback ----------------------------------------------------


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


@pytest.fixture()
def served(tmp_path: Path) -> Iterator[int]:
    """The service as ``serve`` runs it (head timeout 0.5 s), on a free loopback port."""
    settings = Settings(data_dir=tmp_path, tokens=TOKENS, header_timeout_s=0.5)
    port = _free_port()
    config = uvicorn_config(create_app(settings), settings, host="127.0.0.1", port=port)
    config.log_level = logging.WARNING
    server = uvicorn.Server(config)
    thread = threading.Thread(target=server.run, name="uvicorn-edge", daemon=True)
    thread.start()
    deadline = time.monotonic() + 30.0
    while not server.started:
        assert thread.is_alive() and time.monotonic() < deadline, "uvicorn did not start"
        time.sleep(0.01)
    try:
        yield port
    finally:
        server.should_exit = True
        thread.join(timeout=30.0)


def _read_all(sock: socket.socket) -> bytes:
    data = b""
    while chunk := sock.recv(65536):
        data += chunk
    return data


def test_a_30_mb_anonymous_upload_is_answered_401_at_once(served: int) -> None:
    with socket.create_connection(("127.0.0.1", served), timeout=20) as sock:
        started = time.monotonic()
        sock.sendall(
            b"POST /api/passes HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
            + f"Content-Length: {30 * MIB}\r\n\r\n".encode()
            + b'{"name": '
        )
        answer = _read_all(sock)  # the server answers and closes: the rest is never sent
        elapsed = time.monotonic() - started
    assert answer.startswith(b"HTTP/1.1 401 "), answer[:200]
    assert b"connection: close" in answer.lower()
    assert json.loads(answer.split(b"\r\n\r\n", 1)[1])["error"]["code"] == "unauthorized"
    assert elapsed < 10.0


def test_a_connection_without_a_whole_request_head_is_closed(served: int) -> None:
    for partial in (b"GET /api/hea", b""):  # half a request line; nothing at all
        with socket.create_connection(("127.0.0.1", served), timeout=20) as sock:
            started = time.monotonic()
            sock.sendall(partial)
            assert _read_all(sock) == b""  # closed by the server, no answer
            elapsed = time.monotonic() - started
        assert 0.4 <= elapsed < 15.0


def _read_response(sock: socket.socket) -> bytes:
    """One whole HTTP response (head and its Content-Length of body), however the bytes
    arrive: a head and its body may come in separate reads."""
    data = b""
    while b"\r\n\r\n" not in data:
        chunk = sock.recv(65536)
        assert chunk, data
        data += chunk
    head, _, body = data.partition(b"\r\n\r\n")
    length = next(
        int(line.split(b":", 1)[1])
        for line in head.split(b"\r\n")
        if line.lower().startswith(b"content-length:")
    )
    while len(body) < length:
        chunk = sock.recv(65536)
        assert chunk, data
        body += chunk
    assert len(body) == length  # nothing of a next response
    return head + b"\r\n\r\n" + body


def test_a_slow_but_whole_head_is_served_and_the_connection_kept(served: int) -> None:
    with socket.create_connection(("127.0.0.1", served), timeout=20) as sock:
        sock.sendall(b"GET /api/health HTTP/1.1\r\nHo")
        time.sleep(0.2)
        sock.sendall(b"st: x\r\n\r\n")
        first = _read_response(sock)
        assert first.startswith(b"HTTP/1.1 200 "), first
        assert b"server: uvicorn" not in first.lower()
        sock.sendall(b"GET /api/health HTTP/1.1\r\nHost: x\r\n\r\n")  # kept alive
        assert _read_response(sock).startswith(b"HTTP/1.1 200 ")


def test_serve_refuses_a_network_without_tokens(tmp_path: Path) -> None:
    from hikoboshi.cli import app

    env = {"HIKOBOSHI_TOKENS": "", "HIKOBOSHI_DATA_DIR": str(tmp_path), "DATABASE_URL": ""}
    result = CliRunner().invoke(app, ["serve", "--host", "0.0.0.0"], env=env)
    assert result.exit_code == 2
    assert "HIKOBOSHI_TOKENS is empty" in result.output


def test_the_console_files_refuse_control_characters_behind_the_edge(tmp_path: Path) -> None:
    from server.api.errors import HttpError
    from server.api.web import _file

    (tmp_path / "a.js").write_text("x")
    assert _file(tmp_path, "a.js", "no-cache").status_code == 200
    for name in ("a\x00.js", "a\n.js", "a\x7f.js"):
        with pytest.raises(HttpError) as refused:
            _file(tmp_path, name, "no-cache")
        assert refused.value.status == 404
