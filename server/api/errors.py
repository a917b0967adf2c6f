"""One error shape for every failure the API reports, problem details (RFC 9457,
``application/problem+json``), and the one map to it from the errors of the layers below.

    {"type": "urn:hikoboshi:problem:not_found", "title": "Not Found", "status": 404,
     "detail": "pass 1234 does not exist", "code": "not_found", "data": ...,
     "error": {"code": "not_found", "message": "pass 1234 does not exist", "detail": ...}}

``type`` names the code (:data:`PROBLEM_TYPE` + code: a name, not a page to fetch),
``title`` is the status's phrase, ``detail`` the message for a person; the extension members
are ``code`` (the machine-readable reason clients switch on) and ``data`` (what the refusal
carries beside its message, when it carries anything: the failing rows, the window, the
retry time). ``error`` is the shape before problem details, kept as a member so that clients
written against it go on working (docs/security.md "Errors").

The statuses (:func:`describe`): a service's refusal (:mod:`server.services.errors`) by its
kind: not found 404, conflict 409, invalid request 422, unavailable 503 (with
``Retry-After``), deadline exceeded 504, client gone 499, a failed worker job 500; planner
domain errors 422 (the request was understood but cannot be planned), storage ``NotFound``
404, ``Conflict`` 409, ``InvalidArgument`` 400. The API's own refusals (a missing token, a
body over the limit) are :class:`HttpError` with their status; request validation is 422,
a value the database refuses (``DataError``) 400. Nothing a client sends should produce a
500; anything unexpected still answers 500 ``internal_error`` in the shape, without the
traceback (which goes to the log).
"""

from __future__ import annotations

import logging
import math
from http import HTTPStatus
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from sqlalchemy.exc import DataError, OperationalError
from sqlalchemy.exc import TimeoutError as PoolTimeout
from starlette.exceptions import HTTPException as StarletteHTTPException

from planner.errors import PlannerError
from server.services.errors import (
    ClientGoneError,
    ConflictError,
    DeadlineExceededError,
    DomainError,
    InvalidRequestError,
    JobFailedError,
    NotFoundError,
    UnavailableError,
)
from server.storage.errors import Conflict, InvalidArgument, NotFound

__all__ = [
    "PROBLEM_JSON",
    "PROBLEM_TYPE",
    "HttpError",
    "ProblemResponse",
    "describe",
    "install_error_handlers",
    "problem",
    "status_of",
]

log = logging.getLogger("hikoboshi.ground.errors")


class HttpError(Exception):
    """A refusal of the API itself (authentication, the edge's limits, a console file):
    ``status`` (4xx), ``code`` and a message."""

    def __init__(self, status: int, code: str, message: str, detail: Any = None) -> None:
        super().__init__(message)
        self.status = status
        self.code = code
        self.message = message
        self.detail = detail


#: A service's refusal's status, by kind (the first class in the error's MRO listed here).
_DOMAIN_STATUS: dict[type[DomainError], int] = {
    NotFoundError: 404,
    ConflictError: 409,
    InvalidRequestError: 422,
    UnavailableError: 503,
    DeadlineExceededError: 504,
    ClientGoneError: 499,  # nobody reads it; it ends the request (as nginx names it)
    JobFailedError: 500,
}


def describe(exc: BaseException) -> tuple[int, str, str, Any] | None:
    """``(status, code, message, detail)`` the API answers for ``exc``, or None for an
    error that is not a refusal of ours (the framework's and the database's have their own
    handlers below; anything else is a 500)."""
    if isinstance(exc, HttpError):
        return exc.status, exc.code, exc.message, exc.detail
    if isinstance(exc, DomainError):
        status = next(_DOMAIN_STATUS[k] for k in type(exc).__mro__ if k in _DOMAIN_STATUS)
        return status, exc.code, exc.message, exc.detail
    if isinstance(exc, PlannerError):
        return 422, type(exc).__name__, str(exc), None
    if isinstance(exc, NotFound):
        return 404, "not_found", str(exc), None
    if isinstance(exc, Conflict):
        return 409, "conflict", str(exc), None
    if isinstance(exc, InvalidArgument):
        return 400, "invalid_argument", str(exc), None
    return None


def status_of(exc: BaseException) -> int:
    """The HTTP status the API answers ``exc`` with (500 for what it does not map)."""
    described = describe(exc)
    return 500 if described is None else described[0]


#: The media type of every error the API answers (RFC 9457).
PROBLEM_JSON = "application/problem+json"
#: A problem's ``type``: this and its code.
PROBLEM_TYPE = "urn:hikoboshi:problem:"
#: Phrases HTTPStatus does not give: RFC 9110's names (Python 3.11 has the older ones) and
#: nginx's 499.
_TITLES = {413: "Content Too Large", 422: "Unprocessable Content", 499: "Client Closed Request"}


def _title(status: int) -> str:
    if status in _TITLES:
        return _TITLES[status]
    try:
        return HTTPStatus(status).phrase
    except ValueError:
        return "Error"


def problem(status: int, code: str, message: str, detail: Any = None) -> dict[str, Any]:
    """The body of an error: problem details with the code, and the shape before them."""
    body: dict[str, Any] = {
        "type": PROBLEM_TYPE + code,
        "title": _title(status),
        "status": status,
        "detail": message,
        "code": code,
    }
    if detail is not None:
        body["data"] = detail
    body["error"] = {"code": code, "message": message, "detail": detail}
    return body


class ProblemResponse(JSONResponse):
    """A JSON response as ``application/problem+json``."""

    media_type = PROBLEM_JSON


def _json(status: int, code: str, message: str, detail: Any = None) -> JSONResponse:
    return ProblemResponse(status_code=status, content=problem(status, code, message, detail))


def install_error_handlers(app: FastAPI) -> None:
    async def refused(_: Request, exc: Exception) -> JSONResponse:
        described = describe(exc)
        assert described is not None  # registered for the mapped classes only
        response = _json(*described)
        if isinstance(exc, UnavailableError):
            response.headers["Retry-After"] = str(max(1, math.ceil(exc.retry_after_s)))
        return response

    for mapped in (HttpError, DomainError, PlannerError, NotFound, Conflict, InvalidArgument):
        app.add_exception_handler(mapped, refused)

    @app.exception_handler(RequestValidationError)
    async def validation(_: Request, exc: RequestValidationError) -> JSONResponse:
        errors = [
            {"loc": list(e.get("loc", ())), "msg": str(e.get("msg", ""))} for e in exc.errors()
        ]
        message = "; ".join(f"{'.'.join(map(str, e['loc']))}: {e['msg']}" for e in errors[:5])
        return _json(422, "invalid_request", message or "invalid request", errors)

    @app.exception_handler(StarletteHTTPException)
    async def http_error(_: Request, exc: StarletteHTTPException) -> JSONResponse:
        code = {401: "unauthorized", 403: "forbidden", 404: "not_found", 405: "method_not_allowed"}
        return ProblemResponse(
            status_code=exc.status_code,
            content=problem(
                exc.status_code, code.get(exc.status_code, "http_error"), str(exc.detail)
            ),
            headers=getattr(exc, "headers", None),
        )

    @app.exception_handler(DataError)
    async def data_error(request: Request, exc: DataError) -> JSONResponse:
        # A value the database refused (text it cannot store, a number out of range): the
        # edge refuses most of these first (server/api/edge.py). Not the SQL in the answer.
        log.warning(
            "the database refused a value (%s %s): %s", request.method, request.url.path, exc.orig
        )
        return _json(400, "invalid_data", "the database refused a value in the request")

    @app.exception_handler(PoolTimeout)
    async def pool_full(request: Request, exc: PoolTimeout) -> JSONResponse:
        # Every connection of the readers' pool is in use (the command path has its own):
        # come back shortly, rather than wait and hold a thread.
        log.warning("readers' pool full: %s %s", request.method, request.url.path)
        return ProblemResponse(
            status_code=503,
            content=problem(503, "busy", "every database connection for requests is in use"),
            headers={"Retry-After": "2"},
        )

    @app.exception_handler(OperationalError)
    async def database_unavailable(request: Request, exc: OperationalError) -> JSONResponse:
        # The database ended the statement (the readers' statement timeout) or cannot be
        # reached: the request may succeed later.
        cancelled = "statement timeout" in str(exc.orig)
        log.warning(
            "database operational error in %s %s: %s", request.method, request.url.path, exc.orig
        )
        message = (
            "the read took longer than the database allows a request"
            if cancelled
            else "the database is not available"
        )
        return ProblemResponse(
            status_code=503,
            content=problem(503, "busy" if cancelled else "database_unavailable", message),
            headers={"Retry-After": "5"},
        )

    @app.exception_handler(Exception)
    async def unexpected(request: Request, exc: Exception) -> JSONResponse:
        # Starlette calls this from its outermost middleware and then re-raises ``exc``, so
        # the server logs it (with the traceback) as well.
        log.error("unexpected error in %s %s", request.method, request.url.path, exc_info=exc)
        return _json(500, "internal_error", "an unexpected error; it has been logged")
