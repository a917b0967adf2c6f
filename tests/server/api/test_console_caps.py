"""Console caps: at most ``consoles_per_token`` consoles per token holder and
``consoles_per_address`` viewer consoles per address; over a cap the console is closed with
1013 and the reason, and the refusal is in the audit log. Viewers at an operator's address
never lock the operator out; seats are given back when consoles end."""

from __future__ import annotations

import logging
from collections.abc import Iterator
from contextlib import ExitStack
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from starlette.testclient import WebSocketTestSession
from starlette.websockets import WebSocketDisconnect

from server.api.console import CLOSE_OVER_CAP
from server.app import create_app
from server.services.console_seats import ConsoleRefused, ConsoleSeats
from server.settings import ApiToken, Role, Settings
from tests.support.api import ClientAddress

CONSOLE = "/api/console"
TOKENS = {
    **{f"v{k}": ApiToken(name=f"viewer-{k}", role=Role.VIEWER) for k in range(5)},
    "o-token": ApiToken(name="otto", role=Role.OPERATOR),
}
HERE = "198.51.100.1"
THERE = "198.51.100.2"


@pytest.fixture()
def capped(tmp_path: Path) -> Iterator[tuple[TestClient, ConsoleSeats]]:
    """Two consoles per token holder, three viewer consoles per address."""
    settings = Settings(
        data_dir=tmp_path, tokens=TOKENS, consoles_per_token=2, consoles_per_address=3
    )
    app = create_app(settings)
    with TestClient(ClientAddress(app, HERE)) as c:
        yield c, app.state.console_seats


def _headers(token: str, address: str = HERE) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}", "x-test-client": address}


def _open(stack: ExitStack, client: TestClient, token: str, address: str = HERE) -> None:
    """A console that is admitted: its first message is the welcome."""
    ws: WebSocketTestSession = stack.enter_context(
        client.websocket_connect(CONSOLE, headers=_headers(token, address))
    )
    assert ws.receive_json()["type"] == "welcome"


def _refused(client: TestClient, token: str, address: str = HERE) -> WebSocketDisconnect:
    with (
        client.websocket_connect(CONSOLE, headers=_headers(token, address)) as ws,
        pytest.raises(WebSocketDisconnect) as closed,
    ):
        ws.receive_json()
    return closed.value


def test_a_token_holder_is_capped_and_gets_its_seat_back(
    capped: tuple[TestClient, ConsoleSeats], caplog: pytest.LogCaptureFixture
) -> None:
    client, seats = capped
    caplog.set_level(logging.WARNING, logger="hikoboshi.audit")
    with ExitStack() as first:
        _open(first, client, "v0", HERE)
        with ExitStack() as second:
            _open(second, client, "v0", THERE)  # another address: the token's cap still counts
            closed = _refused(client, "v0", "198.51.100.3")
            assert closed.code == CLOSE_OVER_CAP == 1013
            assert "consoles_per_token 2" in closed.reason and "viewer-0" in closed.reason
            assert seats.by_token["viewer-0"] == 2
        # The second console ended: its seat is free again.
        assert seats.by_token["viewer-0"] == 1
        with ExitStack() as again:
            _open(again, client, "v0", THERE)
    assert seats.by_token == {} and seats.by_address == {}
    refusals = [r.getMessage() for r in caplog.records if r.name == "hikoboshi.audit"]
    assert any("console refused" in m and "viewer-0" in m and "per_token" in m for m in refusals), (
        refusals
    )


def test_viewers_at_an_address_are_capped_but_never_lock_out_the_operator(
    capped: tuple[TestClient, ConsoleSeats],
) -> None:
    client, seats = capped
    with ExitStack() as stack:
        for token in ("v0", "v1", "v2"):
            _open(stack, client, token, HERE)
        closed = _refused(client, "v3", HERE)
        assert closed.code == 1013 and "consoles_per_address 3" in closed.reason
        _open(stack, client, "v3", THERE)  # the same holder from elsewhere is welcome
        # The operator at the full address connects, up to the operator's own token cap.
        _open(stack, client, "o-token", HERE)
        _open(stack, client, "o-token", HERE)
        assert _refused(client, "o-token", HERE).code == 1013
        assert seats.by_address == {HERE: 3, THERE: 1}
        assert seats.by_token["otto"] == 2
    assert seats.by_token == {} and seats.by_address == {}


def test_a_refused_authentication_takes_no_seat(
    capped: tuple[TestClient, ConsoleSeats],
) -> None:
    client, seats = capped
    for _ in range(4):
        assert _refused(client, "nope").code == 1008
    assert seats.by_token == {} and seats.by_address == {}


def test_seats_refuse_without_taking() -> None:
    seats = ConsoleSeats(per_token=1, per_address=1)
    with seats.take(holder="a", address="x", operator=False):
        with pytest.raises(ConsoleRefused) as refused:
            seats.take(holder="b", address="x", operator=False)
        assert refused.value.cap == "per_address"
        assert seats.by_token == {"a": 1} and seats.by_address == {"x": 1}
        seat = seats.take(holder="o", address="x", operator=True)
        seat.release()
        seat.release()  # once only
        assert seats.by_token == {"a": 1}
    assert seats.by_token == {} and seats.by_address == {}
    with pytest.raises(ValueError):
        ConsoleSeats(per_token=0, per_address=1)
