"""The console in a real browser: Debian's Chromium (headless, by executable path) driven by
Playwright, against the real ground service (uvicorn on loopback, :mod:`tests.server.link.
harness`) and, where a pass flies, the spacecraft process at 20x in a thread of its own.

Skipped, with the reason, when Chromium or the built console (``web/dist``) is missing;
``scripts/setup.sh --test`` installs both. Every page a test opens collects the browser's
console errors and uncaught exceptions; a test fails if there are any. Screenshots go to
``artifacts/screenshots/`` (git-ignored).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from server.storage.db import sqlite_url
from tests.server.link.harness import Ground, running_ground
from tests.support.web import ROOT, Console, FlyingSpacecraft

CHROMIUM = Path("/usr/bin/chromium")
DIST = ROOT / "web" / "dist"


def _skip_reason() -> str | None:
    if not CHROMIUM.is_file():
        return f"no Chromium at {CHROMIUM} (apt-get install chromium; scripts/setup.sh --test)"
    if not (DIST / "index.html").is_file():
        return f"the console is not built ({DIST}; cd web && npm ci && npm run build)"
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "playwright is not installed (scripts/setup.sh --test)"
    return None


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    """Chromium, one per test module: Playwright's sync API keeps an event loop running in
    this thread while it is open, so every ``asyncio.run`` after it in the same process (a
    test worker goes on to other modules) would fail; a module's tests share one browser."""
    reason = _skip_reason()
    if reason:
        pytest.skip(reason)
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        # --no-sandbox: CI runs as root, where Chromium's sandbox refuses to start.
        browser = pw.chromium.launch(
            executable_path=str(CHROMIUM),
            headless=True,
            args=["--no-sandbox", "--use-gl=swiftshader"],
        )
        try:
            yield browser
        finally:
            browser.close()


@pytest.fixture
def ground(tmp_path: Path) -> Iterator[Ground]:
    with running_ground(sqlite_url(tmp_path)) as g:
        yield g


@pytest.fixture
def console(browser: Any, ground: Ground) -> Iterator[Console]:
    context = browser.new_context(viewport={"width": 1600, "height": 1000})
    page = context.new_page()
    page.set_default_timeout(60_000)  # a guard: planning in a worker on a slow machine
    tab = Console(page, ground.url)
    page.on(
        "console",
        lambda m: tab.errors.append(f"console {m.type}: {m.text}") if m.type == "error" else None,
    )
    page.on("pageerror", lambda e: tab.errors.append(f"page error: {e}"))
    # Names the resource behind Chromium's bare "Failed to load resource" message.
    page.on(
        "response",
        lambda r: (
            tab.errors.append(f"HTTP {r.status} {r.request.method} {r.url}")
            if r.status >= 400
            else None
        ),
    )
    try:
        yield tab
    finally:
        context.close()
    assert tab.errors == [], "errors in the browser:\n" + "\n".join(tab.errors)


@pytest.fixture
def flying(ground: Ground) -> Iterator[FlyingSpacecraft]:
    craft = FlyingSpacecraft(ground)
    try:
        yield craft
    finally:
        craft.stop()
