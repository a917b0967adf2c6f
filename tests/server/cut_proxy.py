"""A TCP proxy in front of the tests' PostgreSQL that a test can cut and restore: a database
outage as the ground sees one (every open connection reset, new ones refused), on the real
server. Threads only; loopback only."""

from __future__ import annotations

import contextlib
import socket
import threading
from collections.abc import Iterator
from contextlib import contextmanager

from sqlalchemy import URL, make_url

__all__ = ["CutProxy", "cut_proxy"]


class CutProxy:
    """Listens on 127.0.0.1:``port`` and forwards each connection to ``upstream``."""

    def __init__(self, upstream: tuple[str, int]) -> None:
        self.upstream = upstream
        self._listener = self._listen(0)
        self.port: int = self._listener.getsockname()[1]
        self._lock = threading.Lock()
        self._sockets: set[socket.socket] = set()
        self._up = True
        self._closed = False
        self.cuts = 0
        self._acceptor = threading.Thread(target=self._accept, name="cut-proxy", daemon=True)
        self._acceptor.start()

    @staticmethod
    def _listen(port: int) -> socket.socket:
        listener = socket.socket()
        listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        listener.bind(("127.0.0.1", port))
        listener.listen(64)
        return listener

    def _accept(self) -> None:
        while not self._closed:
            try:
                client, _ = self._listener.accept()
            except OSError:
                return
            with self._lock:
                up = self._up
            if not up:
                _reset(client)  # the server is "down": refused at once
                continue
            try:
                server = socket.create_connection(self.upstream, timeout=5)
            except OSError:
                _reset(client)
                continue
            server.settimeout(None)
            with self._lock:
                up = self._up  # a cut while this one was connecting takes it too
                if up:
                    self._sockets |= {client, server}
            if not up:
                _reset(client)
                _reset(server)
                continue
            for a, b in ((client, server), (server, client)):
                threading.Thread(target=self._pump, args=(a, b), daemon=True).start()

    def _pump(self, source: socket.socket, sink: socket.socket) -> None:
        try:
            while data := source.recv(65536):
                sink.sendall(data)
        except OSError:
            pass
        finally:
            for s in (source, sink):
                with contextlib.suppress(OSError):
                    s.shutdown(socket.SHUT_RDWR)

    def cut(self) -> None:
        """The database goes away: every connection through the proxy is reset, and new
        ones are refused until :meth:`restore`."""
        with self._lock:
            self._up = False
            sockets, self._sockets = self._sockets, set()
            self.cuts += 1
        for s in sockets:
            _reset(s)

    def restore(self) -> None:
        with self._lock:
            self._up = True

    def close(self) -> None:
        self._closed = True
        self.cut()
        with contextlib.suppress(OSError):
            self._listener.close()


def _reset(s: socket.socket) -> None:
    """Reset the connection (RST, as a server process that died leaves it), waking the
    pump blocked in ``recv`` on it."""
    with contextlib.suppress(OSError):
        s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, b"\x01\x00\x00\x00\x00\x00\x00\x00")
    with contextlib.suppress(OSError):
        s.shutdown(socket.SHUT_RDWR)
    with contextlib.suppress(OSError):
        s.close()


@contextmanager
def cut_proxy(database_url: str) -> Iterator[tuple[CutProxy, str]]:
    """A proxy in front of ``database_url``'s server, and the same URL through it."""
    url: URL = make_url(database_url)
    proxy = CutProxy((url.host or "127.0.0.1", url.port or 5432))
    try:
        yield (
            proxy,
            url.set(host="127.0.0.1", port=proxy.port).render_as_string(hide_password=False),
        )
    finally:
        proxy.close()
