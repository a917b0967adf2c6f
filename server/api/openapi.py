"""Operation ids of the OpenAPI document: the route's function name (``start_pass``,
``list_passes``), stable across path changes and readable in generated clients, instead of
FastAPI's name-path-method concatenation. Route function names are unique across the API
(tests/server/api/test_openapi_rules.py holds them to it).

:func:`file_content` documents a response that is a file rather than JSON (an MCAP, a
Parquet or PNG file, a URDF, a mesh, a report page): a string, binary unless it is text, in
each media type it may come in, so that a generated client reads it as bytes or text
instead of dropping it. :func:`document_problems` says that every error is
``application/problem+json`` (RFC 9457), as the API answers them."""

from __future__ import annotations

from typing import Any

from fastapi import FastAPI
from fastapi.routing import APIRoute

from server.api.errors import PROBLEM_JSON

__all__ = ["document_problems", "file_content", "operation_id"]


def operation_id(route: APIRoute) -> str:
    """The operation id of ``route``: its function's name."""
    return route.name


def file_content(*media_types: str, text: bool = False) -> dict[str, Any]:
    """The OpenAPI ``content`` of a file response in ``media_types``: ``type: string``,
    ``format: binary`` unless ``text``."""
    schema: dict[str, str] = {"type": "string"} if text else {"type": "string", "format": "binary"}
    return {media_type: {"schema": dict(schema)} for media_type in media_types}


def document_problems(app: FastAPI) -> None:
    """Make ``app``'s OpenAPI document describe every 4xx and 5xx answer as
    ``application/problem+json`` (FastAPI files a response model under ``application/json``)."""
    generate = app.openapi

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            document = generate()
            for methods in document.get("paths", {}).values():
                for operation in methods.values():
                    for status, response in operation.get("responses", {}).items():
                        content = response.get("content", {})
                        if status[:1] in "45" and "application/json" in content:
                            content[PROBLEM_JSON] = content.pop("application/json")
        return app.openapi_schema  # type: ignore[return-value]

    app.openapi = openapi  # type: ignore[method-assign]
