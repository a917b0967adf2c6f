"""One spacecraft connection as the ground's link holds it (docs/protocol.md): the accepted
websocket the API layer hands over (:class:`Connection`), and the one way to send on it.

The API layer (``server/api/link.py``) owns the socket and gives :class:`Connection` its
``send_text`` and ``close``; :class:`~server.services.link.GroundLink` keeps the current one
(a newer connection supersedes an older). Sends on one connection are serialised by its
lock; a send that fails (the socket went away under the uplink) is logged once per
connection and counted after that, since a closed link fails every queued command's send.
"""

from __future__ import annotations

import asyncio
import itertools
import logging
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import Any

__all__ = ["Connection"]

log = logging.getLogger("hikoboshi.ground.link")


@dataclass
class Connection:
    """One accepted websocket, as the API layer hands it over."""

    actor: str  # the token holder's name
    send_text: Callable[[str], Awaitable[None]]
    close: Callable[[int, str], Awaitable[None]]
    id: int = field(default_factory=itertools.count(1).__next__)
    greeted: bool = False  # its hello has arrived
    lock: asyncio.Lock = field(default_factory=asyncio.Lock)
    #: who is at the other end, for the takeover audit: the peer's ``host:port`` and
    #: ``User-Agent`` header (None: unknown), and when it connected (ground ns, the
    #: link's clock; stamped by :meth:`GroundLink.attach` when not given)
    peer: str | None = None
    user_agent: str | None = None
    connected_ns: int | None = None
    #: sends that failed on it (the socket went away under the uplink): the first is
    #: logged, the rest counted, as a closed link fails every queued command's send
    send_failures: int = 0

    def described(self) -> dict[str, Any]:
        """This connection as the takeover event names it."""
        return {
            "connection": self.id,
            "actor": self.actor,
            "peer": self.peer,
            "user_agent": self.user_agent,
            "connected_ns": self.connected_ns,
        }

    async def send(self, text: str) -> bool:
        """Send one message; False when it failed (counted, the first logged)."""
        try:
            async with self.lock:
                await self.send_text(text)
        except Exception as exc:  # the socket went away under us
            self.send_failures += 1
            if self.send_failures == 1:
                log.warning(
                    "send to spacecraft failed on connection %d: %r (further failures on it"
                    " are counted, not logged)",
                    self.id,
                    exc,
                )
            return False
        return True

    def log_failures(self) -> None:
        """At its detach: how many sends failed after the first was logged."""
        if self.send_failures > 1:
            log.warning(
                "connection %d: %d sends failed after its socket went away",
                self.id,
                self.send_failures,
            )
