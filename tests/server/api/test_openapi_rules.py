"""The OpenAPI document states the rules the server enforces on a request (docs/security.md,
*The OpenAPI document*): every free-text string a client sends carries the text rule as a
``pattern`` and a ``maxLength``; the patterns mean the same to Python, to ECMA-262 (the
dialect JSON Schema names) and to schemathesis's generator; ``OPTIONS`` answers ``Allow``.

The whole API against its document is tests/server/api/test_schemathesis.py."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import schemathesis
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, given, settings
from schemathesis.python.asgi import shutdown_lifespans

from server.app import create_app
from server.schemas import LINE_PATTERN, NAME_TEXT_PATTERN, TEXT_PATTERN, name_problem
from server.settings import Settings
from tests.support.api import OPERATOR, TOKENS

#: What a name may not hold beyond the body's rule (server.schemas.NAME_TEXT_PATTERN): C1,
#: bidi controls, zero-width and invisible format characters, separators, noncharacters.
NAME_REFUSED = ["\x85", "\x9f", "a\u202eb", "\u061c", "a\u200db", "\u2066", "\u2028",
                "\ufeff", "\ufdd0", "\uffff"]  # fmt: skip
#: Strings that probe the patterns: each C0 control, DEL, C1, and text that must pass.
PROBES = [
    *(chr(c) for c in range(0x20)),
    "\x7f",
    "\x85",
    "a\tb",
    "line\nbreak",
    "cr\r",
    "trailing\n",
    "START pass 1",
    "Ünïcödé",
    "軌道",
    "🛰 satellite",
    "",
    "e\u0301",  # a combining accent: a name may hold it
    *NAME_REFUSED,
]
#: What the edge refuses in a JSON body's strings, and in a path or query string.
_BODY_REFUSED = [chr(c) for c in [*range(0x09), 0x0B, 0x0C, *range(0x0E, 0x20), 0x7F]]
_LINE_REFUSED = [chr(c) for c in [*range(0x20), 0x7F]]


def _matches(pattern: str, text: str) -> bool:
    """Whether ``pattern`` matches ``text`` as ECMA-262 (and pydantic's Rust engine) read it:
    a final ``$`` is the end of the text, where Python's also matches before a final
    newline."""
    return re.search(pattern.removesuffix("$") + r"\Z", text) is not None


@pytest.fixture(scope="module")
def document(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    app = create_app(Settings(data_dir=tmp_path_factory.mktemp("openapi")))
    schema: dict[str, Any] = app.openapi()
    return schema


def _resolve(document: dict[str, Any], schema: dict[str, Any]) -> dict[str, Any]:
    while "$ref" in schema:
        name = schema["$ref"].rsplit("/", 1)[-1]
        schema = document["components"]["schemas"][name]
    return schema


def _strings(
    document: dict[str, Any], schema: dict[str, Any], where: str, seen: set[str]
) -> Iterator[tuple[str, dict[str, Any]]]:
    """Every string schema a request may hold under ``schema``: (where, schema)."""
    ref = schema.get("$ref")
    if ref is not None:
        if ref in seen:
            return
        seen = {*seen, ref}
    schema = _resolve(document, schema)
    if schema.get("type") == "string":
        yield where, schema
    for key in ("anyOf", "oneOf", "allOf"):
        for i, sub in enumerate(schema.get(key, ())):
            yield from _strings(document, sub, f"{where}|{i}", seen)
    for name, sub in schema.get("properties", {}).items():
        yield from _strings(document, sub, f"{where}.{name}", seen)
    for key in ("items", "additionalProperties"):
        if isinstance(schema.get(key), dict):
            yield from _strings(document, schema[key], f"{where}[{key}]", seen)
    if schema.get("type") == "object" and "propertyNames" in schema:
        yield f"{where}{{keys}}", {"type": "string", **schema["propertyNames"]}


def _request_strings(document: dict[str, Any]) -> Iterator[tuple[str, str, dict[str, Any]]]:
    """(operation, where, string schema) of every parameter and JSON body string."""
    for path, item in document["paths"].items():
        for method, operation in item.items():
            label = f"{method.upper()} {path}"
            for parameter in operation.get("parameters", ()):
                if parameter["in"] == "header":
                    continue  # Authorization: HTTP itself (h11) refuses control characters
                where = f"{parameter['in']} {parameter['name']}"
                for at, schema in _strings(document, parameter["schema"], where, set()):
                    yield label, at, schema
            body = operation.get("requestBody", {}).get("content", {})
            if "application/json" in body:
                for at, schema in _strings(document, body["application/json"]["schema"], "", set()):
                    yield label, f"body{at}", schema


def test_every_free_text_string_a_client_sends_states_the_text_rule_and_a_length(
    document: dict[str, Any],
) -> None:
    strings = list(_request_strings(document))
    assert len(strings) > 20
    unruled = []
    for label, where, schema in strings:
        if "enum" in schema or "const" in schema or schema.get("format") in ("date-time",):
            continue  # a closed vocabulary or a format: no free text
        refused = _BODY_REFUSED if where.startswith("body") else _LINE_REFUSED
        pattern = schema.get("pattern")
        # the shared pattern, or a stricter one of its own (a robot's name, a hash)
        keeps_rule = pattern is not None and not any(
            _matches(pattern, text) for c in refused for text in (c, f"a{c}b", f"a{c}")
        )
        bounded = "maxLength" in schema or pattern == r"^[0-9a-f]{64}$"
        if not (keeps_rule and bounded):
            unruled.append(f"{label} {where}: {schema}")
    assert not unruled, "\n".join(unruled)


def test_request_bodies_take_no_keys_they_do_not_declare(document: dict[str, Any]) -> None:
    bodies = {
        f"{method.upper()} {path}": _resolve(
            document, operation["requestBody"]["content"]["application/json"]["schema"]
        )
        for path, item in document["paths"].items()
        for method, operation in item.items()
        if "application/json" in operation.get("requestBody", {}).get("content", {})
    }
    assert len(bodies) >= 6

    def is_closed(body: dict[str, Any]) -> bool:
        # a body of alternatives (POST /api/passes: times, or a named window) is closed when
        # each alternative is
        alternatives = body.get("anyOf") or body.get("oneOf")
        if alternatives:
            return all(is_closed(_resolve(document, alt)) for alt in alternatives)
        return body.get("additionalProperties") is False

    closed = {label for label, body in bodies.items() if is_closed(body)}
    assert set(bodies) - closed == set()


@pytest.mark.parametrize(
    "pattern", [TEXT_PATTERN, LINE_PATTERN, NAME_TEXT_PATTERN], ids=["text", "line", "name"]
)
def test_the_patterns_mean_the_same_in_python_and_ecma_262(pattern: str) -> None:
    node = shutil.which("node")
    if node is None:
        pytest.skip("node (an ECMA-262 engine) is not installed")
    script = (
        "const [pattern, probes] = JSON.parse(require('fs').readFileSync(0, 'utf8'));"
        "const plain = new RegExp(pattern), unicode = new RegExp(pattern, 'u');"
        "console.log(JSON.stringify(probes.map((s) => [plain.test(s), unicode.test(s)])));"
    )
    out = subprocess.run(
        [node, "-e", script],
        input=json.dumps([pattern, PROBES]),
        capture_output=True,
        text=True,
        check=True,
        timeout=60,  # a guard, not a timing assertion
    ).stdout
    ecma = json.loads(out)
    python = [_matches(pattern, s) for s in PROBES]
    assert [plain for plain, _ in ecma] == python
    assert [unicode for _, unicode in ecma] == python
    # and what they mean: tab, newline, CR in body text only; no other C0, no DEL
    allowed = {s for s, ok in zip(PROBES, python, strict=True) if ok}
    body_controls = {"\t", "\n", "\r", "a\tb", "line\nbreak", "cr\r", "trailing\n"}
    assert {"\x00", "\x1b", "\x7f"} & allowed == set()
    assert {"軌道", "🛰 satellite", "e\u0301", ""} <= allowed
    if pattern == TEXT_PATTERN:
        assert body_controls <= allowed
    else:
        assert body_controls & allowed == set()
    if pattern == NAME_TEXT_PATTERN:  # and the validator says the same, naming the character
        assert set(NAME_REFUSED) & allowed == set()
        assert [name_problem(s) is None for s in PROBES] == python
    else:
        assert set(NAME_REFUSED) <= allowed


def test_schemathesis_generates_from_the_patterns(tmp_path: Path) -> None:
    """Generation from the ECMA patterns works: the strings drawn for a path parameter and a
    body's text match the server's own rule, and are not only ASCII."""
    app = create_app(Settings(data_dir=tmp_path, tokens=TOKENS))
    try:
        schema = schemathesis.openapi.from_asgi("/openapi.json", app)
    finally:
        shutdown_lifespans()
    abort = schema["/api/passes/{pass_id}/abort"]["POST"]
    drawn: list[str] = []

    @settings(
        max_examples=60,
        derandomize=True,
        database=None,
        deadline=None,
        suppress_health_check=list(HealthCheck),
    )
    @given(case=abort.as_strategy())
    def draw(case: Any) -> None:
        pass_id = case.path_parameters["pass_id"]
        assert _matches(LINE_PATTERN, pass_id), repr(pass_id)
        for text in (case.body["confirm"], case.body.get("reason", "")):
            assert _matches(TEXT_PATTERN, text), repr(text)
        drawn.extend([pass_id, case.body["confirm"]])

    draw()
    assert drawn
    assert any(not s.isascii() for s in drawn), drawn[:10]


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    """One application for the module: its tests only ask (a few failed authentications,
    far under the edge's limit per address)."""
    settings = Settings(data_dir=tmp_path_factory.mktemp("app"), tokens=TOKENS)
    with TestClient(create_app(settings)) as c:
        yield c


@pytest.mark.parametrize(
    ("path", "allow"),
    [
        ("/api/passes", "GET, OPTIONS, POST"),
        ("/api/passes/some-id", "GET, OPTIONS"),
        ("/api/passes/import", "OPTIONS, POST"),  # not /api/passes/{pass_id}'s GET
        ("/api/passes/some-id/report/figures/a.png", "GET, OPTIONS"),
        ("/api/alarms/some-id/acknowledge", "OPTIONS, POST"),
        ("/api/health", "GET, OPTIONS"),
        ("/openapi.json", "GET, HEAD, OPTIONS"),
    ],
)
def test_options_answers_204_with_the_paths_methods(
    client: TestClient, path: str, allow: str
) -> None:
    response = client.options(path, headers=OPERATOR)
    assert response.status_code == 204
    assert response.headers["allow"] == allow
    assert response.content == b""


def test_options_on_an_api_route_needs_a_token_and_an_unknown_path_is_404(
    client: TestClient,
) -> None:
    assert client.options("/api/passes").status_code == 401
    assert client.options("/api/nothing-here", headers=OPERATOR).status_code == 404


def test_a_405_still_names_the_methods(client: TestClient) -> None:
    response = client.delete("/api/passes", headers=OPERATOR)
    assert response.status_code == 405
    assert set(response.headers["allow"].replace(" ", "").split(",")) >= {"GET", "POST"}


def test_operations_declare_the_bearer_scheme_instead_of_a_header_parameter(
    document: dict[str, Any],
) -> None:
    assert document["components"]["securitySchemes"]["bearerAuth"] == {
        "type": "http",
        "scheme": "bearer",
        "description": document["components"]["securitySchemes"]["bearerAuth"]["description"],
    }
    operations = [(path, op) for path, item in document["paths"].items() for op in item.values()]
    secured = [path for path, op in operations if op.get("security") == [{"bearerAuth": []}]]
    open_ = [path for path, op in operations if "security" not in op]
    # liveness, readiness and command authority: public (an orchestrator's probes)
    assert sorted(open_) == ["/api/command", "/api/health", "/api/ready"]
    assert len(secured) == len(operations) - 3 >= 27
    headers = [
        (path, p["name"])
        for path, op in operations
        for p in op.get("parameters", [])
        if p["in"] == "header"
    ]
    assert headers == []  # no optional `authorization` parameter left anywhere


def test_operation_ids_are_the_route_names(document: dict[str, Any]) -> None:
    ids = {
        (method, path): op["operationId"]
        for path, item in document["paths"].items()
        for method, op in item.items()
    }
    assert len(set(ids.values())) == len(ids)
    assert ids["post", "/api/passes/{pass_id}/start"] == "start_pass"
    assert ids["get", "/api/passes"] == "list_passes"
    assert ids["get", "/api/passes/{pass_id}/recording.mcap"] == "download_recording"
    assert all(re.fullmatch(r"[a-z][a-z0-9_]*", i) and "_api_" not in i for i in ids.values())


@pytest.mark.parametrize(
    ("headers", "status", "message"),
    [
        ({}, 401, "an API token is required (Authorization: Bearer)"),
        ({"Authorization": "Basic o-token"}, 401, "an API token is required"),
        ({"Authorization": "Bearer nope"}, 401, "unknown API token"),
        ({"Authorization": "Bearer v-token"}, 403, "role 'viewer' may not do this"),
    ],
)
def test_auth_answers_as_before_behind_the_declared_scheme(
    client: TestClient, headers: dict[str, str], status: int, message: str
) -> None:
    response = client.post("/api/passes/x/start", headers=headers, json={})
    assert response.status_code == status, response.text
    assert response.json()["error"]["message"].startswith(message)


def test_every_file_response_is_documented_as_a_string(document: dict[str, Any]) -> None:
    """A generated client drops a response whose content has no schema: every success
    response that is not JSON (MCAP, Parquet, CSV, PNG, URDF, meshes, the report page) is a
    string, binary unless its media type is text."""
    files = {}
    for path, methods in document["paths"].items():
        for method, operation in methods.items():
            for status, response in operation["responses"].items():
                if not status.startswith("2"):
                    continue
                for media_type, content in response.get("content", {}).items():
                    assert "schema" in content, (method, path, status, media_type)
                    if media_type != "application/json":
                        files[(path, media_type)] = content["schema"]
    textual = ("text/", "application/xml")
    for (path, media_type), schema in files.items():
        assert schema["type"] == "string", (path, media_type)
        assert (schema.get("format") == "binary") != media_type.startswith(textual), (
            path,
            media_type,
        )
    assert {media_type for _, media_type in files} >= {
        "application/octet-stream",
        "application/vnd.apache.parquet",
        "image/png",
        "model/stl",
        "text/csv",
        "application/xml",
        "text/html",
    }


def test_every_schema_has_a_name_of_its_own(document: dict[str, Any]) -> None:
    """Two models of one name are told apart by FastAPI with their module path
    (``server__schemas__CommandPublic``), and client generators refuse the pair (the
    commands' listing went missing from a generated client): names are unique."""
    qualified = [name for name in document["components"]["schemas"] if "__" in name]
    assert qualified == []
