"""The console in a real browser, as the browser tests drive it: the tokens it signs in
with, a page of it (:class:`Console`), a pass stored with its frames, and a spacecraft
process flying beside it (:class:`FlyingSpacecraft`). The fixtures that make them are
tests/web/conftest.py's."""

from __future__ import annotations

import asyncio
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from planner.plan import Plan
from server.storage import repository as repo
from telemetry.layout import FrameLayout
from tests.server.link.harness import Ground, spacecraft
from tests.server.storage.factories import make_frames

ROOT = Path(__file__).resolve().parents[2]


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
