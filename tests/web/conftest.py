"""The console in a real browser: Debian's Chromium (headless, by executable path) driven by
Playwright, against the real ground service (uvicorn on loopback, :mod:`tests.server.link.
harness`) and, where a pass flies, the spacecraft process at 20x in a thread of its own.

Skipped, with the reason, when Chromium or the built console (``web/dist``) is missing;
``scripts/setup.sh --test`` installs both. Every page a test opens collects the browser's
console errors and uncaught exceptions; a test fails if there are any. Screenshots go to
``artifacts/screenshots/`` (git-ignored).
"""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

from planner.plan import Plan
from server.storage import repository as repo
from server.storage.db import sqlite_url
from telemetry.layout import FrameLayout
from tests.server.link.harness import Ground, running_ground, spacecraft
from tests.server.storage.factories import make_frames

CHROMIUM = Path("/usr/bin/chromium")
ROOT = Path(__file__).resolve().parents[2]
DIST = ROOT / "web" / "dist"
SCREENSHOTS = ROOT / "artifacts" / "screenshots"

OPERATOR_TOKEN = "o-token"
VIEWER_TOKEN = "v-token"


def stored_pass(ground: Ground, name: str, plan: Plan, n_frames: int) -> str:
    """A pass of ``plan`` in the ground's archive with ``n_frames`` frames of its robot."""
    now = time.time_ns()
    layout = FrameLayout(len(plan.initial_joints_rad), 3)
    with ground.sessions() as session:
        record = repo.add_pass(
            session=session,
            name=name,
            plan_id=repo.add_plan(session=session, plan=plan, created_at_ns=now).id,
            aos_time_ns=now,
            los_time_ns=now + 10**12,
            relay="TDRS-W",
            created_at_ns=now,
        )
        repo.ingest_frames(
            session=session,
            pass_id=record.id,
            frames=make_frames(range(n_frames), layout=layout),
            reception_time_ns=now,
        )
        session.commit()
        return record.id


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


@dataclass
class Console:
    """One browser tab on the console, with what went wrong in it."""

    page: Any
    base_url: str
    errors: list[str] = field(default_factory=list)

    def sign_in(self, token: str, route: str = "") -> None:
        self.page.goto(f"{self.base_url}/{route}")
        self.page.fill("[data-test=token]", token)
        self.page.click("[data-test=signin]")
        self.page.wait_for_selector("[data-test=role]")

    def wait(self, expression: str, what: str, timeout_ms: float = 60_000) -> None:
        """Wait for a JS condition; on timeout fail with a screenshot and the page's state."""
        from playwright.sync_api import TimeoutError as PlaywrightTimeout

        try:
            self.page.wait_for_function(expression, timeout=timeout_ms)
        except PlaywrightTimeout:
            shot = self.screenshot(f"failed-{what.replace(' ', '-')}")
            state = self.page.evaluate(
                "() => ({points: window.hikoboshiLive?.pointCounts(),"
                " frames: window.hikoboshiLive?.frames(),"
                " socket: document.querySelector('[data-test=socket-state]')?.textContent,"
                " link: document.querySelector('[data-test=link]')?.innerText,"
                " state: document.querySelector('[data-test=pass-state]')?.textContent})"
            )
            raise AssertionError(
                f"{what}: not within {timeout_ms} ms; {state}; see {shot}"
            ) from None

    def screenshot(self, name: str) -> Path:
        SCREENSHOTS.mkdir(parents=True, exist_ok=True)
        path = SCREENSHOTS / f"{name}.png"
        self.page.screenshot(path=str(path), full_page=True)
        return path


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


class FlyingSpacecraft:
    """The spacecraft process (20x) in a thread with its own event loop, until stopped."""

    def __init__(self, ground: Ground, **link: Any):
        self.process, self.generated = spacecraft(ground, **link)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Event | None = None
        self._ready = threading.Event()
        self._thread = threading.Thread(target=self._run, name="spacecraft", daemon=True)
        self._thread.start()
        assert self._ready.wait(10.0), "the spacecraft thread did not start"

    def _run(self) -> None:
        async def main() -> None:
            self._loop = asyncio.get_running_loop()
            self._stop = asyncio.Event()
            self._ready.set()
            await self.process.run(self._stop)

        asyncio.run(main())

    def stop(self) -> None:
        """Stop (draining every frame to the ground); again is a no-op."""
        if not self._thread.is_alive():
            return
        if self._loop is not None and self._stop is not None:
            self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(timeout=60.0)
        assert not self._thread.is_alive(), "the spacecraft did not stop"


@pytest.fixture
def flying(ground: Ground) -> Iterator[FlyingSpacecraft]:
    craft = FlyingSpacecraft(ground)
    try:
        yield craft
    finally:
        craft.stop()
