"""The HTTP edge (server/api/edge.py, docs/security.md): authentication before any body is
read, the size and depth limits, text the databases refuse, the failed-authentication
limit, the security headers, constant-time tokens, and how ``serve`` runs uvicorn."""

from __future__ import annotations

import asyncio
import contextlib
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

import httpx
import pytest
import uvicorn
from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy.exc import DataError
from starlette.types import Message, Scope
from starlette.websockets import WebSocketDisconnect
from typer.testing import CliRunner

from server.api import deps
from server.api.auth_guard import AuthGuard
from server.api.edge_checks import check_json
from server.api.http_server import uvicorn_config
from server.app import create_app
from server.redaction import RedactSecretsFilter
from server.settings import ApiToken, Role, Settings
from server.storage import repository as repo
from tests.server.storage.factories import make_plan
from tests.support.api import OPERATOR, TOKENS, VIEWER, ClientAddress, add_pass, sessions
from tests.support.processes import free_port

MIB = 1024 * 1024
JSON = {"Content-Type": "application/json"}


def _error(response: Any) -> str:
    assert response.headers["content-type"] == "application/problem+json", response.text
    code: str = response.json()["error"]["code"]
    return code


def _nothing_stored(client: TestClient) -> None:
    with sessions(client)() as session:
        assert repo.list_passes(session=session).count == 0
        assert repo.list_events(session=session).count == 0


@pytest.fixture(scope="module")
def shared_client(module_client: TestClient) -> TestClient:
    """One application per module and backend, for the refusals that pass the token check
    or come before it: none stores a row or an event, and ``_nothing_stored`` says so."""
    return module_client


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


def test_a_declared_body_over_the_limit_is_refused_unread(shared_client: TestClient) -> None:
    headers = {**OPERATOR, "content-type": "application/json", "content-length": str(2 * MIB)}
    call = Call([b"{}"]).run(shared_client.app, "POST", "/api/passes", headers)
    assert (call.status, call.code, call.read) == (413, "request_too_large", 0)


def test_a_streamed_body_is_cut_off_past_the_limit(shared_client: TestClient) -> None:
    chunks = [b" " * 256 * 1024] * 16  # 4 MiB, no content-length
    headers = {**OPERATOR, "content-type": "application/json", "transfer-encoding": "chunked"}
    call = Call(chunks).run(shared_client.app, "POST", "/api/passes", headers)
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
def test_json_bodies_are_checked_before_the_route(
    shared_client: TestClient, body: str, code: str
) -> None:
    response = shared_client.post(
        "/api/passes", content=body.encode(), headers={**OPERATOR, **JSON}
    )
    assert (response.status_code, _error(response)) == (400, code), response.text
    assert response.json()["error"]["message"]
    _nothing_stored(shared_client)


def test_a_body_without_a_content_type_is_checked_as_json(shared_client: TestClient) -> None:
    # FastAPI reads a body without a content type as JSON: so does the edge.
    response = shared_client.post("/api/passes", content=b'{"name": "\\u0000"}', headers=OPERATOR)
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


def test_a_deep_but_allowed_body_reaches_the_route(shared_client: TestClient) -> None:
    body = {"plan_id": "p", "name": [[[[1]]]]}
    response = shared_client.post("/api/passes", json=body, headers=OPERATOR)
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
    shared_client: TestClient, path: str, headers: dict[str, str]
) -> None:
    response = shared_client.get(path, headers=headers)
    assert (response.status_code, _error(response)) == (400, "invalid_text")
    assert response.headers["x-content-type-options"] == "nosniff"


def test_ordinary_queries_still_pass(shared_client: TestClient) -> None:
    response = shared_client.get("/api/plans?experiment=ptp%20x&limit=5", headers=VIEWER)
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


@pytest.fixture()
def limited(tmp_path: Path) -> Iterator[tuple[TestClient, list[float]]]:
    """An application allowing 3 failures a minute, and its guard's clock (settable)."""
    settings = Settings(
        data_dir=tmp_path, tokens=TOKENS, auth_failure_limit=3, auth_failure_window_s=60.0
    )
    app = create_app(settings)
    now = [1000.0]
    app.state.auth_guard.clock = lambda: now[0]
    with TestClient(ClientAddress(app, "203.0.113.1")) as c:
        yield c, now


SPACECRAFT = {"Authorization": "Bearer s-token"}


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
        # The limit is reached: a failing attempt from there is 429, whatever it presents,
        # neither checked further nor audited again...
        for headers in ({"Authorization": "Bearer wrong-secret-4"}, {}):
            response = client.get("/api/passes", headers={**attacker, **headers})
            assert (response.status_code, _error(response)) == (429, "too_many_failures")
            assert response.headers["retry-after"] == "60"
        # ... but a valid token, the health check and the console's files are answered.
        assert client.get("/api/passes", headers={**attacker, **VIEWER}).status_code == 200
        assert client.get("/api/health", headers=attacker).status_code == 200
        assert client.get("/", headers=attacker).status_code in (200, 503)  # 503: unbuilt
        response = client.get("/assets/a%00.js", headers=attacker)
        assert (response.status_code, _error(response)) == (400, "invalid_text")
    audited = [r.getMessage() for r in caplog.records if r.name == "hikoboshi.audit"]
    assert len(audited) == 4  # three failures, one "refused"
    assert all("198.51.100.7" in line for line in audited)
    assert "path='/api/passes'" in audited[0] and "an API token is required" in audited[0]
    assert "unknown API token" in audited[2] and "credential=hmac:" in audited[2]
    assert not any("wrong-secret" in line for line in audited)

    # Another address is not affected.
    other = {"x-test-client": "198.51.100.8", "Authorization": "Bearer other-wrong"}
    assert client.get("/api/passes", headers=other).status_code == 401
    # The window runs out.
    bad = {**attacker, "Authorization": "Bearer wrong-secret-5"}
    now[0] += 30.0
    response = client.get("/api/passes", headers=bad)
    assert (response.status_code, response.headers["retry-after"]) == (429, "30")
    now[0] += 30.0
    assert client.get("/api/passes", headers=bad).status_code == 401


def test_200_wrong_tokens_never_keep_out_the_operator_health_or_the_vehicle(
    limited: tuple[TestClient, list[float]],
) -> None:
    """The issue's must-show, in process: 200 wrong tokens from one address (the limit is
    3 here), then an operator's abort, the health check and the vehicle's link from the
    same address: all answered as from anywhere else, none 429 or refused at the handshake.
    (Over a real server and a real spacecraft: test_the_vehicle_reconnects_...)."""
    client, _ = limited
    shared = "198.51.100.30"  # a reverse proxy's address, say: everyone's
    for i in range(200):
        headers = {"x-test-client": shared, "Authorization": f"Bearer wrong-{i}"}
        assert client.get("/api/passes", headers=headers).status_code in (401, 429)
    wrong = {"x-test-client": shared, "Authorization": "Bearer wrong-201"}
    assert client.get("/api/passes", headers=wrong).status_code == 429
    here = {"x-test-client": shared}
    # The operator's abort reaches its route (no such pass: 404, not the edge's 401/429).
    response = client.post(
        "/api/passes/p-none/abort",
        json={"confirm": "ABORT p-none", "reason": "test"},
        headers={**here, **OPERATOR},
    )
    assert (response.status_code, _error(response)) == (404, "not_found"), response.text
    assert client.get("/api/health", headers=here).status_code == 200
    # The vehicle's link with its token connects: the ground reads what it sends (and
    # answers a message it cannot read with ``error``, where a refused link is closed).
    with client.websocket_connect("/api/link", headers={**here, **SPACECRAFT}) as ws:
        ws.send_text("not a message")
        assert ws.receive_json()["type"] == "error"
    # ... while a wrong token on the link is refused, with the reason.
    with (
        client.websocket_connect("/api/link", headers=wrong) as ws,
        pytest.raises(WebSocketDisconnect) as closed,
    ):
        ws.receive_text()
    assert closed.value.code == 1008
    assert "too many failed authentications" in (closed.value.reason or "")


def test_failures_are_counted_per_credential_too(
    limited: tuple[TestClient, list[float]],
) -> None:
    """One wrong token tried from many addresses (a client behind rotating addresses, a
    stale token everywhere) is refused once over the limit, from a fresh address too; a
    different wrong token from that fresh address is still heard (401)."""
    client, _ = limited
    stale = {"Authorization": "Bearer stale-token"}
    for i in range(3):
        headers = {"x-test-client": f"198.51.100.{40 + i}", **stale}
        assert client.get("/api/passes", headers=headers).status_code == 401
    fresh = {"x-test-client": "198.51.100.99"}
    response = client.get("/api/passes", headers={**fresh, **stale})
    assert (response.status_code, _error(response)) == (429, "too_many_failures")
    other = {**fresh, "Authorization": "Bearer another-wrong"}
    assert client.get("/api/passes", headers=other).status_code == 401
    guard = client.app.app.state.auth_guard  # type: ignore[attr-defined]  # inside ClientAddress
    assert guard.credentials_tracked() == 2 and len(guard) == 4


def test_a_blocked_address_is_one_event_in_the_audit_log(
    limited: tuple[TestClient, list[float]],
) -> None:
    """The events table (what consoles and ``GET /api/events`` show) gets one
    ``auth_blocked`` per blocked window and address, however many failures follow."""
    client, now = limited
    attacker = {"x-test-client": "198.51.100.20"}
    for i in range(10):
        client.get("/api/passes", headers={**attacker, "Authorization": f"Bearer nope-{i}"})

    factory = client.app.app.state.sessions  # type: ignore[attr-defined]  # inside ClientAddress

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
    for i in range(3):
        client.get("/api/passes", headers={**attacker, "Authorization": f"Bearer again-{i}"})
    deadline = time.monotonic() + 30.0
    while len(blocked()) < 2:
        assert time.monotonic() < deadline, "no second auth_blocked event"
        time.sleep(0.05)
    time.sleep(0.2)
    assert len(blocked()) == 2


def test_websocket_failures_count_too(limited: tuple[TestClient, list[float]]) -> None:
    client, _ = limited
    here = {"x-test-client": "198.51.100.9"}
    for i, path in enumerate(("/api/link", "/api/console", "/api/link")):
        bad = {**here, "Authorization": f"Bearer nope-{i}"}
        with client.websocket_connect(path, headers=bad) as ws, pytest.raises(WebSocketDisconnect):
            ws.receive_text()
    # Over the limit: a failing attempt is refused with the reason, on HTTP too...
    bad = {**here, "Authorization": "Bearer nope-3"}
    with (
        client.websocket_connect("/api/console", headers=bad) as ws,
        pytest.raises(WebSocketDisconnect) as closed,
    ):
        ws.receive_text()
    assert "too many failed authentications" in (closed.value.reason or "")
    assert client.get("/api/passes", headers=bad).status_code == 429
    # ... a console's first-message token too; a valid token is never refused.
    with client.websocket_connect("/api/console", headers=here) as ws:
        ws.send_text(json.dumps({"v": 1, "type": "auth", "token": "nope-4"}))
        with pytest.raises(WebSocketDisconnect) as closed:
            ws.receive_text()
    assert "too many failed authentications" in (closed.value.reason or "")
    with client.websocket_connect("/api/console", headers={**here, **VIEWER}) as ws:
        assert ws.receive_json()["type"]
    assert client.get("/api/passes", headers={**here, **VIEWER}).status_code == 200


def test_the_guard_tracks_a_bounded_number_of_addresses_and_credentials() -> None:
    now = [0.0]
    guard = AuthGuard(limit=2, window_s=10.0, max_addresses=3, clock=lambda: now[0])
    for i in range(5):
        guard.failed(f"10.0.0.{i}", "/api/x", "unknown API token", f"wrong-{i}")
        now[0] += 1.0
    assert len(guard) == 3 and guard.credentials_tracked() == 3  # the oldest two went
    guard.failed("10.0.0.4", "/api/x", "unknown API token")
    assert guard.retry_after("10.0.0.4") == 9  # its window started at 4 s, it is 5 s now
    assert guard.retry_after("10.0.0.5", "wrong-4") is None  # once for this credential
    guard.failed("10.0.0.5", "/api/x", "unknown API token", "wrong-4")
    assert guard.retry_after("10.0.0.6", "wrong-4") == 9  # from any address
    assert guard.retry_after("10.0.0.6", "wrong-3") is None
    now[0] = 100.0
    assert guard.retry_after("10.0.0.4", "wrong-4") is None and len(guard) == 0
    assert guard.credentials_tracked() == 0


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


@contextlib.contextmanager
def _serving(settings: Settings) -> Iterator[int]:
    """``settings``' service as ``serve`` runs it (:func:`uvicorn_config`), on a free
    loopback port, in a thread."""
    port = free_port()
    config = uvicorn_config(
        create_app(settings), settings, host="127.0.0.1", port=port, log_level="warning"
    )
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


@pytest.fixture()
def served(tmp_path: Path) -> Iterator[int]:
    """The service as ``serve`` runs it (head timeout 0.5 s), on a free loopback port."""
    with _serving(Settings(data_dir=tmp_path, tokens=TOKENS, header_timeout_s=0.5)) as port:
        yield port


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


# --- forwarded headers and the failed-authentication limit over a real server -------------


def _audited(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.name == "hikoboshi.audit"]


def test_serve_believes_forwarded_headers_from_no_one_by_default() -> None:
    settings = Settings(tokens=TOKENS)
    config = uvicorn_config(FastAPI(), settings, host="127.0.0.1", port=1)
    assert config.proxy_headers is False  # uvicorn's default believes loopback
    trusted = Settings(tokens=TOKENS, trusted_proxies=("10.0.0.2", "172.16.0.0/12"))
    config = uvicorn_config(FastAPI(), trusted, host="127.0.0.1", port=1)
    assert config.proxy_headers is True
    assert config.forwarded_allow_ips == ["10.0.0.2", "172.16.0.0/12"]


def test_trusted_proxies_are_addresses_from_the_environment(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setenv("HIKOBOSHI_TRUSTED_PROXIES", " 10.0.0.2, fd00::/8 ,")
    assert Settings.from_env().trusted_proxies == ("10.0.0.2", "fd00::/8")
    monkeypatch.delenv("HIKOBOSHI_TRUSTED_PROXIES")
    assert Settings.from_env().trusted_proxies == ()
    with pytest.raises(ValueError, match=r"'proxy\.example' is not an IP address"):
        Settings(trusted_proxies=("proxy.example",))


def test_a_spoofed_forwarded_for_from_an_untrusted_peer_changes_nothing(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """From loopback, which uvicorn's default believes: wrong tokens with a new
    ``X-Forwarded-For`` each are all the peer's (429 past the limit), and an address named
    in one is neither counted nor blocked."""
    settings = Settings(data_dir=tmp_path, tokens=TOKENS, auth_failure_limit=5)
    with (
        caplog.at_level(logging.WARNING, logger="hikoboshi.audit"),
        _serving(settings) as port,
        httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=20.0) as http,
    ):
        statuses = [
            http.get(
                "/api/passes",
                headers={"Authorization": f"Bearer wrong-{i}", "X-Forwarded-For": f"203.0.113.{i}"},
            ).status_code
            for i in range(12)
        ]
        assert statuses == [401] * 5 + [429] * 7
        forged = {"X-Forwarded-For": "198.51.100.77"}
        assert http.get("/api/passes", headers={**forged, **VIEWER}).status_code == 200
        assert http.get("/api/health", headers=forged).status_code == 200
    audited = _audited(caplog)
    assert len(audited) == 6  # five failures, one "refused", all the peer's
    assert all("address=127.0.0.1 " in a or "address 127.0.0.1 " in a for a in audited)
    assert not any("203.0.113." in a or "198.51.100.77" in a for a in audited)


def test_forwarded_for_is_believed_from_a_trusted_proxy(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Behind the reverse proxy (named in ``trusted_proxies``) each client is counted as
    itself: one over the limit leaves the others heard."""
    settings = Settings(
        data_dir=tmp_path, tokens=TOKENS, auth_failure_limit=2, trusted_proxies=("127.0.0.1",)
    )
    with (
        caplog.at_level(logging.WARNING, logger="hikoboshi.audit"),
        _serving(settings) as port,
        httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=20.0) as http,
    ):

        def get(client: str, token: str) -> int:
            headers = {"Authorization": f"Bearer {token}", "X-Forwarded-For": client}
            return http.get("/api/passes", headers=headers).status_code

        assert [get("203.0.113.1", f"wrong-{i}") for i in range(3)] == [401, 401, 429]
        assert get("203.0.113.2", "wrong-x") == 401
        assert get("203.0.113.1", "v-token") == 200
    audited = _audited(caplog)
    assert sum("address=203.0.113.1 " in a for a in audited) == 2
    assert sum("address=203.0.113.2 " in a for a in audited) == 1
    assert not any("127.0.0.1" in a for a in audited)


@pytest.mark.slow
@pytest.mark.realtime
def test_the_vehicle_reconnects_after_200_wrong_tokens_from_its_address(tmp_path: Path) -> None:
    """The issue's must-show over a real server (as ``serve`` runs it) and the real
    spacecraft process: 200 wrong tokens from loopback, the vehicle's own address, on REST
    and on the link; then the operator's abort, the health check and the vehicle's
    reconnection (its link dropped) are all answered. SQLite only: nothing here is about the
    database (the edge counts in memory, before any route)."""
    from spacecraft.link import LinkConfig
    from spacecraft.process import ProcessConfig, SpacecraftProcess

    settings = Settings(data_dir=tmp_path, tokens=TOKENS)  # the default limit: 20 a minute
    processes: list[SpacecraftProcess] = []

    async def connected(
        http: httpx.AsyncClient, process: SpacecraftProcess, connections: int
    ) -> None:
        deadline = time.monotonic() + 60.0  # a guard, not a timing assertion
        while True:
            status = (await http.get("/api/link/status", headers=VIEWER)).json()
            if status["connected"] and process.connections >= connections:
                return
            assert time.monotonic() < deadline, f"not connected ({process.connections})"
            await asyncio.sleep(0.05)

    async def scenario(port: int) -> None:
        import websockets

        process = SpacecraftProcess(
            ProcessConfig(
                ground_url=f"ws://127.0.0.1:{port}/api/link",
                token="s-token",
                time_scale=10.0,
                uplink=LinkConfig(seed=1),
                downlink=LinkConfig(seed=2),
                seed=3,
                backoff_initial_s=0.05,
                backoff_max_s=0.5,
                drain_timeout_s=5.0,
            )
        )
        processes.append(process)
        stop = asyncio.Event()
        flying = asyncio.create_task(process.run(stop))
        async with httpx.AsyncClient(base_url=f"http://127.0.0.1:{port}", timeout=20.0) as http:
            try:
                await connected(http, process, 1)
                for i in range(200):
                    headers = {"Authorization": f"Bearer wrong-{i}"}
                    response = await http.get("/api/passes", headers=headers)
                    assert response.status_code in (401, 429)
                wrong = {"Authorization": "Bearer wrong-link"}
                async with websockets.connect(
                    f"ws://127.0.0.1:{port}/api/link", additional_headers=wrong
                ) as ws:
                    with pytest.raises(websockets.ConnectionClosed) as closed:
                        await ws.recv()
                assert closed.value.rcvd is not None
                assert "too many failed" in closed.value.rcvd.reason
                assert response.status_code == 429  # the address is over the limit
                response = await http.post(
                    "/api/passes/p-none/abort",
                    json={"confirm": "ABORT p-none", "reason": "test"},
                    headers=OPERATOR,
                )
                assert (response.status_code, _error(response)) == (404, "not_found")
                assert (await http.get("/api/health")).status_code == 200
                # The link drops; the vehicle reconnects from the same address.
                assert process._ws is not None
                await process._ws.close()
                await connected(http, process, 2)
            finally:
                stop.set()
                await asyncio.wait_for(flying, 60.0)  # a guard against a hang

    with _serving(settings) as port:
        asyncio.run(scenario(port))
    assert [p.connections for p in processes] == [2]
