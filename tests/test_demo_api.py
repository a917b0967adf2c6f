"""The demo's REST client (hikoboshi/demo_harness.py ``_Api``) turns a ground that does not answer
into the demo's own error with a reason, not a traceback: a crowded machine once made the
pass's planning request outlast the client's timeout and the demo died with
``TimeoutError: timed out``."""

from __future__ import annotations

import socket
import threading
from collections.abc import Iterator

import pytest

from hikoboshi.demo_harness import DemoError, _Api


@pytest.fixture()
def silent_server() -> Iterator[str]:
    """A loopback server that accepts connections and never answers."""
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen()
    accepted: list[socket.socket] = []
    done = threading.Event()

    def accept() -> None:
        listener.settimeout(0.1)
        while not done.is_set():
            try:
                accepted.append(listener.accept()[0])
            except TimeoutError:
                continue

    thread = threading.Thread(target=accept, name="silent-server")
    thread.start()
    try:
        yield f"http://127.0.0.1:{listener.getsockname()[1]}"
    finally:
        done.set()
        thread.join()
        for conn in accepted:
            conn.close()
        listener.close()


def test_a_ground_that_does_not_answer_is_a_demo_error_naming_the_request(
    silent_server: str,
) -> None:
    api = _Api(silent_server, "token")
    with pytest.raises(DemoError) as raised:
        api.call("POST", "/api/plans", {"experiment": "pass"}, timeout_s=0.5)
    message = str(raised.value)
    assert message.startswith("POST /api/plans: no answer from the ground service within 0.5 s")
    assert "ground.log" in message


def test_a_ground_that_is_gone_is_a_demo_error_too() -> None:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]  # closed again: nothing listens there
    with pytest.raises(
        DemoError, match=r"^GET /api/link/status: http://127.0.0.1:\d+ refused the connection"
    ):
        _Api(f"http://127.0.0.1:{port}", "token").call("GET", "/api/link/status", timeout_s=2.0)
