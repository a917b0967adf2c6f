"""A console the server says is behind shows it, and a resync for being behind reloads the
pass's snapshot over REST while the socket goes on (docs/console.md, "A console behind").

A browser on loopback reads as fast as it is sent to, so the server's word (``lag``, then
``resync``) is put on the console's queue in the server's own loop; how the hub measures a
console's lag and decides is tested in ``tests/server/console/test_backpressure.py``.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from typing import Any

import pytest

from server.services.console import ConsoleHub
from server.services.console_messages import LagMsg, ResyncMsg
from tests.server.link.harness import Ground
from tests.server.storage.factories import make_plan
from tests.support.web import VIEWER_TOKEN, Console, stored_pass

pytestmark = pytest.mark.realtime  # flies a vehicle or serves a live link in wall time

BEHIND = "[data-test=behind]"


def _on_server(ground: Ground, fn: Callable[[ConsoleHub], None]) -> None:
    """Run ``fn(hub)`` in the server's event loop (the hub is not thread-safe)."""
    hub: ConsoleHub = ground.app.state.console
    assert hub._lag_watch is not None
    loop = hub._lag_watch.get_loop()

    async def run() -> None:
        fn(hub)

    asyncio.run_coroutine_threadsafe(run(), loop).result(10.0)


def _lag(behind_s: float) -> Callable[[ConsoleHub], None]:
    def tell(hub: ConsoleHub) -> None:
        message = LagMsg(
            behind_s=behind_s,
            queued=1234 if behind_s else 0,
            resync_s=hub.limits.behind_resync_s,
            time_ns=time.time_ns(),
        )
        for client in list(hub._clients):
            client.control(message)

    return tell


def _quiet(hub: ConsoleHub) -> None:
    """The hub's own lag watch says nothing in this test (a browser busy drawing on a
    loaded machine can be half a second behind, truly): the test's word is the only one."""
    hub.limits.behind_report_s = hub.limits.behind_resync_s = hub.limits.behind_drop_s = 1e9


def _resync_commands(hub: ConsoleHub) -> None:
    stream = hub._streams[("commands", None)]
    reason = "behind by 6.1 s, more than 5 s: 900 messages not sent; reload the snapshot"
    for client in list(hub._clients):
        client.control(
            ResyncMsg(topic="commands", epoch=hub.epoch, seq=stream.last_seq, reason=reason)
        )


def _shown(page: Any) -> bool:
    return not page.is_hidden(BEHIND)


def test_the_console_shows_how_far_behind_it_is_and_reloads_on_a_resync(
    console: Console, ground: Ground
) -> None:
    pass_id = stored_pass(ground, "behind", make_plan(n_joints=6), 30)
    _on_server(ground, _quiet)
    page = console.page
    console.sign_in(VIEWER_TOKEN, f"#/live/{pass_id}")
    console.wait("() => window.hikoboshiLive?.frames() === 30", "the archive loaded")
    assert not _shown(page)  # nobody said it is behind
    # The page acknowledges what it reads: the server holds its unread data to its window.
    acking: list[bool] = []
    _on_server(ground, lambda hub: acking.extend(c.acks for c in hub._clients))
    assert acking == [True]

    _on_server(ground, _lag(3.2))
    console.wait(f"() => !document.querySelector('{BEHIND}').hidden", "behind shown")
    assert page.text_content(BEHIND) == "⚠ view behind by 3.2 s"
    assert page.get_attribute(BEHIND, "data-value") == "3.2"
    console.screenshot("console-behind")

    # Behind past the bound: the server dropped the backlog and says resync; the live page
    # reloads the pass's commands (the snapshot) and the indicator says so.
    commands = f"/api/passes/{pass_id}/commands"
    with page.expect_request(lambda r: commands in r.url, timeout=20_000):
        _on_server(ground, _resync_commands)
    console.wait(
        f"() => document.querySelector('{BEHIND}').textContent.endsWith(': reloaded')",
        "resync shown",
    )
    assert "behind by 6.1 s, more than 5 s" in (page.text_content(BEHIND) or "")
    assert (page.text_content("[data-test=socket-state]") or "").endswith("console connected")

    # Caught up: the indicator goes (after being shown for at least 2 s).
    _on_server(ground, _lag(0.0))
    console.wait(f"() => document.querySelector('{BEHIND}').hidden", "behind cleared")
    assert page.get_attribute(BEHIND, "data-value") == "0"
