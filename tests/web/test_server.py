"""Serving the console (no browser): the built page, its assets, the 503 that says how to
build it, nothing outside the build; and the console's experiment table against the
planner's catalogue."""

from __future__ import annotations

import dataclasses
import json
import typing
from pathlib import Path

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from planner.catalogue import experiments
from planner.coordination import OFFSET_WINDOWS
from server.api.errors import install_error_handlers
from server.api.web import make_router

pytestmark = pytest.mark.realtime  # flies a vehicle or serves a live link in wall time

EXPERIMENTS_JSON = Path(__file__).resolve().parents[2] / "web/src/pages/experiments.json"


def _client(dist: Path) -> TestClient:
    app = FastAPI(docs_url=None, redoc_url=None)  # as the service: /docs is the build's
    install_error_handlers(app)
    app.include_router(make_router(dist))
    return TestClient(app)


def test_an_unbuilt_console_answers_503_with_how_to_build_it(tmp_path: Path) -> None:
    response = _client(tmp_path / "dist").get("/")
    assert response.status_code == 503
    assert "not built" in response.text
    assert "scripts/setup.sh" in response.text and "npm run build" in response.text


def test_the_built_console_and_its_assets_are_served(tmp_path: Path) -> None:
    (tmp_path / "assets").mkdir()
    (tmp_path / "model").mkdir()
    (tmp_path / "index.html").write_text("<!doctype html><title>console</title>")
    (tmp_path / "assets" / "main-ABC.js").write_text("console.log(1)")
    (tmp_path / "model" / "ets7.urdf").write_text("<robot/>")
    (tmp_path / "secret.py").write_text("no")
    client = _client(tmp_path)
    index = client.get("/")
    assert index.status_code == 200 and "console" in index.text
    assert index.headers["cache-control"] == "no-cache"
    script = client.get("/assets/main-ABC.js")
    assert script.status_code == 200
    assert script.headers["content-type"].startswith("text/javascript")
    assert "immutable" in script.headers["cache-control"]
    assert client.get("/model/ets7.urdf").headers["content-type"].startswith("application/xml")
    for path in ("/assets/missing.js", "/assets/..%2Fsecret.py", "/assets/%2E%2E/secret.py"):
        response = client.get(path)
        assert response.status_code == 404, path
    assert client.get("/assets/../secret.py").status_code == 404


def test_the_console_route_is_not_in_the_openapi_document(tmp_path: Path) -> None:
    assert _client(tmp_path).get("/openapi.json").json()["paths"] == {}


def _default_text(value: object) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, tuple):
        return ",".join(_default_text(v) for v in value)
    return repr(value)


@pytest.mark.parametrize("name", sorted(experiments()))
def test_the_console_offers_the_planner_parameters_with_their_defaults(name: str) -> None:
    table = json.loads(EXPERIMENTS_JSON.read_text())
    assert sorted(table) == sorted(experiments())
    params_type, _ = experiments()[name]
    hints = typing.get_type_hints(params_type)
    fields = dataclasses.fields(params_type)
    assert [p["name"] for p in table[name]["params"]] == [f.name for f in fields]
    for spec, f in zip(table[name]["params"], fields, strict=True):
        default = f.default
        if f.default_factory is not dataclasses.MISSING:
            default = f.default_factory()
        optional = type(None) in typing.get_args(hints[f.name])
        assert spec.get("optional", False) == optional, f.name
        # Same value, as the console shows it (spaces and float spelling aside).
        shown = [s.strip() for s in spec["default"].split(",")] if spec["default"] else []
        expected = [s for s in _default_text(default).split(",") if s != ""]
        if spec["type"] in ("float", "floats"):
            assert [float(s) for s in shown] == [float(s) for s in expected], f.name
        else:
            assert [s.strip("'") for s in shown] == [s.strip("'") for s in expected], f.name
        if "choices" in spec:  # offered as a list: the default is one of them
            assert spec["default"] in spec["choices"], f.name
    if name == "coordination":
        (window,) = (p for p in table[name]["params"] if p["name"] == "offset_window")
        assert window["choices"] == list(OFFSET_WINDOWS)


def test_without_a_build_the_api_docs_answer_503_and_point_to_the_document(
    tmp_path: Path,
) -> None:
    response = _client(tmp_path / "dist").get("/docs")
    assert response.status_code == 503
    assert 'href="/openapi.json"' in response.text and "scripts/setup.sh" in response.text
