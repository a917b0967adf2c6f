"""Operation ids of the OpenAPI document: the route's function name (``start_pass``,
``list_passes``), stable across path changes and readable in generated clients, instead of
FastAPI's name-path-method concatenation. Route function names are unique across the API
(tests/server/api/test_openapi_rules.py holds them to it)."""

from __future__ import annotations

from fastapi.routing import APIRoute

__all__ = ["operation_id"]


def operation_id(route: APIRoute) -> str:
    """The operation id of ``route``: its function's name."""
    return route.name
