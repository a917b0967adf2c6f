"""Property-based tests of the whole REST API from its own OpenAPI document (schemathesis):
whatever a client sends that the schema allows, the service answers without a 5xx, with a
status it documents, in the schema it documents.

In process: schemathesis calls the ASGI app while a ``TestClient`` holds its lifespan open
(the database stays migrated and reachable). Examples per operation are bounded so the run
stays well under a minute per backend.
"""

from __future__ import annotations

from typing import Any

import pytest
import schemathesis
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from schemathesis.checks import not_a_server_error
from schemathesis.specs.openapi.checks import (
    content_type_conformance,
    response_schema_conformance,
    status_code_conformance,
)

from server.api import analyses as analyses_api
from server.api import control as control_api
from server.api import model as model_api
from server.api import passes as passes_api
from server.api import plans as plans_api
from server.api import recordings as recordings_api
from server.api import robots as robots_api
from server.api import telemetry as telemetry_api
from tests.server.api.conftest import OPERATOR

CHECKS = [
    not_a_server_error,
    status_code_conformance,
    content_type_conformance,
    response_schema_conformance,
]
EXAMPLES_PER_OPERATION = 25
#: The operations of these routers (start, abort and the link's status included; the link's
#: websocket has its own tests).
ROUTERS = (
    control_api.router,
    plans_api.router,
    passes_api.router,
    telemetry_api.router,
    analyses_api.router,
    recordings_api.router,
    model_api.router,
    robots_api.router,
)


def _ours() -> set[tuple[str, str]]:
    return {
        (method, route.path)
        for router in ROUTERS
        for route in router.routes
        for method in getattr(route, "methods", ())
    }


@pytest.mark.slow
def test_every_operation_conforms_and_never_fails_on_the_server(client: TestClient) -> None:
    schema = schemathesis.openapi.from_asgi("/openapi.json", client.app)
    ours = _ours()
    operations = [
        op
        for op in (result.ok() for result in schema.get_all_operations())
        if (op.method.upper(), op.path) in ours
    ]
    assert len(operations) == len(ours) == 28
    for operation in operations:

        @settings(
            max_examples=EXAMPLES_PER_OPERATION,
            deadline=None,
            database=None,
            suppress_health_check=list(HealthCheck),
        )
        @given(case=operation.as_strategy(), data=st.data())
        def check(case: Any, data: st.DataObject) -> None:
            response = case.call(headers=OPERATOR)
            case.validate_response(response, checks=CHECKS)

        check()
