"""One JSON error shape for every failure the API reports, and the map from domain errors.

    {"error": {"code": "not_found", "message": "pass 1234 does not exist", "detail": ...}}

Planner domain errors are 422 (the request was understood but cannot be planned), storage
``NotFound`` 404, ``Conflict`` 409, ``InvalidArgument`` 400, service errors their own 4xx,
request validation 422, a value the database refuses (``DataError``) 400. Nothing a client
sends should produce a 500; anything unexpected still answers 500 ``internal_error`` in the
shape, without the traceback (which goes to the log).
"""

from __future__ import annotations

import logging
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from sqlalchemy.exc import DataError, OperationalError
from sqlalchemy.exc import TimeoutError as PoolTimeout
from starlette.exceptions import HTTPException as StarletteHTTPException

from planner.errors import PlannerError
from server.storage.errors import Conflict, InvalidArgument, NotFound

__all__ = ["ServiceError", "error_body", "install_error_handlers"]

log = logging.getLogger("hikoboshi.ground.errors")


class ServiceError(Exception):
    """A request the service refuses: ``status`` (4xx), ``code`` and a message."""

    def __init__(self, status: int, code: str, message: str, detail: Any = None) -> None:
        super().__init__(message)
        self.status = status
        self.code = code
        self.message = message
        self.detail = detail


def error_body(code: str, message: str, detail: Any = None) -> dict[str, Any]:
    return {"error": {"code": code, "message": message, "detail": detail}}


def _json(status: int, code: str, message: str, detail: Any = None) -> JSONResponse:
    return JSONResponse(status_code=status, content=error_body(code, message, detail))


def install_error_handlers(app: FastAPI) -> None:
    @app.exception_handler(ServiceError)
    async def service_error(_: Request, exc: ServiceError) -> JSONResponse:
        return _json(exc.status, exc.code, exc.message, exc.detail)

    @app.exception_handler(PlannerError)
    async def planner_error(_: Request, exc: PlannerError) -> JSONResponse:
        return _json(422, type(exc).__name__, str(exc))

    @app.exception_handler(NotFound)
    async def not_found(_: Request, exc: NotFound) -> JSONResponse:
        return _json(404, "not_found", str(exc))

    @app.exception_handler(Conflict)
    async def conflict(_: Request, exc: Conflict) -> JSONResponse:
        return _json(409, "conflict", str(exc))

    @app.exception_handler(InvalidArgument)
    async def invalid(_: Request, exc: InvalidArgument) -> JSONResponse:
        return _json(400, "invalid_argument", str(exc))

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
        return JSONResponse(
            status_code=exc.status_code,
            content=error_body(code.get(exc.status_code, "http_error"), str(exc.detail)),
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
        return JSONResponse(
            status_code=503,
            content=error_body("busy", "every database connection for requests is in use"),
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
        return JSONResponse(
            status_code=503,
            content=error_body("busy" if cancelled else "database_unavailable", message),
            headers={"Retry-After": "5"},
        )

    @app.exception_handler(Exception)
    async def unexpected(request: Request, exc: Exception) -> JSONResponse:
        # Starlette calls this from its outermost middleware and then re-raises ``exc``, so
        # the server logs it (with the traceback) as well.
        log.error("unexpected error in %s %s", request.method, request.url.path, exc_info=exc)
        return _json(500, "internal_error", "an unexpected error; it has been logged")
