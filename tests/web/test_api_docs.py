"""The API's documentation page in a real browser, offline: ``/docs`` draws every operation of
the OpenAPI document with Swagger UI served from the ground's own build, and no request
leaves the ground (every other host is refused by the test)."""

from __future__ import annotations

import re
from typing import Any

import httpx
import pytest

from tests.server.link.harness import Ground

pytestmark = pytest.mark.realtime  # serves the ground in wall time


def test_the_api_docs_work_offline(browser: Any, ground: Ground) -> None:
    operations = sum(
        len(methods) for methods in httpx.get(f"{ground.url}/openapi.json").json()["paths"].values()
    )
    context = browser.new_context()
    page = context.new_page()
    page.set_default_timeout(60_000)  # a guard on a slow machine
    outside: list[str] = []

    def only_the_ground(route: Any) -> None:
        if route.request.url.startswith(ground.url):
            route.continue_()
        else:
            outside.append(route.request.url)
            route.abort()

    page.route("**/*", only_the_ground)
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    try:
        page.goto(f"{ground.url}/docs")
        page.wait_for_selector(".opblock")
        drawn = page.locator(".opblock").count()
        title = page.locator(".information-container .title").inner_text()
    finally:
        context.close()
    assert outside == [] and errors == []
    assert "Hikoboshi ground service" in title
    assert drawn == operations > 30


def test_the_docs_page_names_only_the_grounds_own_files(ground: Ground) -> None:
    page = httpx.get(f"{ground.url}/docs")
    assert page.status_code == 200
    assert "/swagger/swagger-ui-bundle.js" in page.text and "/swagger/swagger-ui.css" in page.text
    linked = re.findall(r"""(?:src|href|url)\s*[=:]\s*['"]([^'"]+)['"]""", page.text)
    assert linked and all(link.startswith("/") for link in linked), linked
    script = httpx.get(f"{ground.url}/swagger/swagger-ui-bundle.js")
    assert script.status_code == 200 and script.headers["content-type"].startswith(
        "text/javascript"
    )
    assert httpx.get(f"{ground.url}/redoc").status_code == 404
