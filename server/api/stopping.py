"""The answer of a request the stopping server cut short: 503 ``shutting_down`` in the JSON
error shape (:mod:`server.api.errors`), never the HTTP server's plain-text 500
(docs/operations.md "Stopping").

On SIGTERM ``hikoboshi serve`` first stops the worker pool, whose waiting and running
requests answer ``shutting_down`` themselves (:mod:`server.services.workers`); uvicorn then
waits a few seconds for the requests still in flight and cancels the rest. Such a request
(one queued in a lane, say) would be answered by uvicorn with a plain-text 500: this
middleware, the outermost of the application's own, answers it instead, when no response
has started (one that has, a file being streamed, can only be cut).
"""

from __future__ import annotations

import asyncio
import json
import math

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from server.api.errors import PROBLEM_JSON, problem
from server.services.workers import STOPPING_RETRY_AFTER_S

__all__ = ["AnswerWhenStopping"]


class AnswerWhenStopping:
    """Pure ASGI: an HTTP request whose task is cancelled before its response started is
    answered 503 ``shutting_down`` with ``Retry-After``."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        started = False

        async def sending(message: Message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, receive, sending)
        except asyncio.CancelledError:
            if started:
                raise
            task = asyncio.current_task()
            if task is not None:
                task.uncancel()  # answered here: the cancellation has done its work
            await _answer(send)


async def _answer(send: Send) -> None:
    body = json.dumps(
        problem(
            503,
            "shutting_down",
            "the service is shutting down; the request was stopped, try again after it restarts",
            {"retry_after_s": STOPPING_RETRY_AFTER_S},
        )
    ).encode()
    await send(
        {
            "type": "http.response.start",
            "status": 503,
            "headers": [
                (b"content-type", PROBLEM_JSON.encode()),
                (b"content-length", str(len(body)).encode()),
                (b"retry-after", str(math.ceil(STOPPING_RETRY_AFTER_S)).encode()),
                (b"connection", b"close"),
            ],
        }
    )
    await send({"type": "http.response.body", "body": body})
