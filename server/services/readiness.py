"""Readiness (``GET /api/ready``): the service is ready when its database answers and the
database's schema is at the head migration; else the reason.

Liveness (``/api/health``) touches nothing; readiness asks the database, on its own
connection (a pool of one, never one the readers, the operators or the link use), in its
own thread, at most one question at a time: probes that arrive while one is in flight share
its answer, and one that waits longer than :data:`READY_TIMEOUT_S` answers "did not answer"
(a hung database holds one thread, never more). A change between ready and not ready is
logged once (not each probe).
"""

from __future__ import annotations

import asyncio
import logging
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

from sqlalchemy import text

from server.storage.db import (
    READ_ONLY_OPTION,
    PoolSizes,
    current_revisions,
    head_revisions,
    make_engine,
)

__all__ = ["READY_TIMEOUT_S", "Readiness", "ReadinessProbe"]

log = logging.getLogger("hikoboshi.ground.readiness")

#: How long a probe waits for the database's answer (s).
READY_TIMEOUT_S = 2.0


@dataclass(frozen=True)
class Readiness:
    ready: bool
    code: str  # ready, database_unavailable, database_timeout, schema_not_at_head
    message: str
    detail: dict[str, Any] = field(default_factory=dict)


class ReadinessProbe:
    """Asks the database at ``url`` whether it answers and is at the head migration."""

    def __init__(self, url: str, *, timeout_s: float = READY_TIMEOUT_S) -> None:
        self.timeout_s = timeout_s
        self._engine = make_engine(
            url,
            pool=PoolSizes(size=1, overflow=0, timeout_s=timeout_s, statement_timeout_s=timeout_s),
        )
        self._reader = self._engine.execution_options(**{READ_ONLY_OPTION: True})
        self._head: tuple[str, ...] | None = None
        self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="readiness")
        self._inflight: asyncio.Future[Readiness] | None = None
        self._last: bool | None = None

    def check_now(self) -> Readiness:
        """The answer, asked now (blocking: in the probe's thread)."""
        if self._head is None:
            self._head = head_revisions()
        head = self._head
        try:
            with self._reader.connect() as connection:
                connection.execute(text("SELECT 1"))
                current = current_revisions(connection)
        except Exception as exc:
            # The error's text may name hosts and users: in the log, not in the answer.
            return Readiness(
                False,
                "database_unavailable",
                "the database does not answer",
                {"error": type(exc).__name__, "_text": str(exc).splitlines()[0][:300]},
            )
        if current != head:
            at = ", ".join(current) or "no migration"
            return Readiness(
                False,
                "schema_not_at_head",
                f"the database schema is at {at}, not at the head migration {', '.join(head)}",
                {"current": list(current), "head": list(head)},
            )
        return Readiness(True, "ready", "ready", {"migration": list(head)})

    async def check(self) -> Readiness:
        """The answer, at most :attr:`timeout_s` from now (see the module doc)."""
        loop = asyncio.get_running_loop()
        if self._inflight is None or self._inflight.done():
            self._inflight = loop.run_in_executor(self._executor, self.check_now)
        try:
            answer = await asyncio.wait_for(asyncio.shield(self._inflight), self.timeout_s)
        except TimeoutError:
            answer = Readiness(
                False,
                "database_timeout",
                f"the database did not answer within {self.timeout_s:g} s",
            )
        detail = dict(answer.detail)
        error_text = detail.pop("_text", None)
        if answer.ready != self._last:
            self._last = answer.ready
            if answer.ready:
                log.info("ready: the database answers at the head migration")
            else:
                log.warning(
                    "not ready: %s%s",
                    answer.message,
                    f" ({error_text})" if error_text else "",
                    extra={"fields": {"event": "not_ready", "reason": answer.code}},
                )
        return Readiness(answer.ready, answer.code, answer.message, detail)

    def close(self) -> None:
        self._executor.shutdown(wait=False, cancel_futures=True)
        self._engine.dispose()
