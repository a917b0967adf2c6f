"""Ports and processes of the tests' servers (``hikoboshi serve``: its command, its
environment, its health once up), and the lock processes share."""

from __future__ import annotations

import contextlib
import fcntl
import os
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on now."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


def serve_command(port: int) -> list[str]:
    """``hikoboshi serve`` on ``port``, run by this interpreter."""
    return [sys.executable, "-m", "hikoboshi", "serve", "--port", str(port)]


def serve_env(data_dir: Path, tokens: str, **more: str) -> dict[str, str]:
    """This environment for a ``hikoboshi serve`` of its own: its data (SQLite database
    included: no ``DATABASE_URL``) in ``data_dir``, the API tokens ``tokens``."""
    env = {
        **os.environ,
        "HIKOBOSHI_DATA_DIR": str(data_dir),
        "HIKOBOSHI_TOKENS": tokens,
        **more,
    }
    env.pop("DATABASE_URL", None)
    return env


def health_when_up(
    proc: subprocess.Popen[Any],
    base: str,
    *,
    guard_s: float = 60.0,
    request_timeout_s: float = 1.0,
    output: Callable[[], str] | None = None,
) -> httpx.Response:
    """The answer of the server at ``base`` (``proc``) to ``/api/health``, asked again until
    it comes; a failure if the process ends first (with ``output()``, else its stderr if
    piped) or after ``guard_s`` (a hang guard, not a timing assertion)."""
    deadline = time.monotonic() + guard_s
    while True:
        try:
            return httpx.get(f"{base}/api/health", timeout=request_timeout_s)
        except httpx.TransportError:
            if proc.poll() is not None:
                said = output() if output else proc.stderr.read() if proc.stderr else ""
                raise AssertionError(f"the server exited: {said}") from None
            assert time.monotonic() < deadline, "the server did not come up"
            time.sleep(0.1)


def descendants(pid: int) -> set[int]:
    """Every process below ``pid`` (from /proc: psutil is not a dependency)."""
    children: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as stat:
                fields = stat.read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        children.setdefault(int(fields[1]), []).append(int(entry))
    found: set[int] = set()
    todo = [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            found.add(child)
            todo.append(child)
    return found


def stderr_of_stopped(proc: subprocess.Popen[str], timeout_s: float) -> str:
    """Wait for ``proc`` (a ``hikoboshi serve``, ``stderr=PIPE``) to exit and return what it
    wrote to stderr, without waiting for the pipe's end: its forkserver holds the pipe open
    until it has finished its imports and seen the server gone, seconds after a server
    stopped right after it started. Whatever the server wrote is in the pipe once it has
    exited (Python flushes stderr at exit)."""
    proc.wait(timeout=timeout_s)
    assert proc.stderr is not None
    fd = proc.stderr.fileno()
    os.set_blocking(fd, False)
    chunks = []
    while True:
        try:
            chunk = os.read(fd, 1 << 16)
        except BlockingIOError:  # all there is, the forkserver still holding the pipe
            break
        if not chunk:
            break
        chunks.append(chunk)
    proc.stderr.close()
    return b"".join(chunks).decode()


@contextlib.contextmanager
def flocked(path: Path) -> Iterator[None]:
    """An exclusive ``flock`` on the file ``path`` (made if missing) while inside."""
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o600)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # releases the lock
