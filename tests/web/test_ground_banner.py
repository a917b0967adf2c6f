"""The console on a standby ground says so on every page, naming the ground in command, and
the strip goes when this ground takes the command over (docs/operations.md "One ground in
command"). Two grounds on one PostgreSQL; the browser on the second."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import ExitStack
from typing import Any

import pytest

from tests.server.link.harness import Ground, running_ground
from tests.support.web import OPERATOR_TOKEN, Console

pytestmark = pytest.mark.realtime


@pytest.fixture
def grounds(postgres_schema_url: str) -> Iterator[tuple[ExitStack, Ground]]:
    """Ground A (the holder; the test stops it by closing the returned stack) and ground B,
    a standby, which the console opens."""
    lease: dict[str, Any] = {"lease_ttl_s": 3.0, "lease_renew_s": 0.5}
    with ExitStack() as first:
        first.enter_context(running_ground(postgres_schema_url, ground_name="ground-a", **lease))
        with running_ground(postgres_schema_url, ground_name="ground-b", **lease) as b:
            yield first, b


@pytest.fixture
def ground(grounds: tuple[ExitStack, Ground]) -> Ground:
    return grounds[1]


def test_a_standby_s_console_names_the_ground_in_command(
    console: Console, grounds: tuple[ExitStack, Ground]
) -> None:
    first, b = grounds
    assert b.app.state.authority.status()["role"] == "standby"
    page = console.page
    console.sign_in(OPERATOR_TOKEN, "#/passes")
    page.wait_for_selector("[data-test=ground-banner]:not([hidden])")
    text = page.text_content("[data-test=ground-banner]") or ""
    assert text.startswith("STANDBY GROUND: ground-a:"), text
    assert "starts and aborts go there" in text
    console.screenshot("standby-ground")
    # the holder stops (its lease released): this ground takes the command, the strip goes
    first.close()
    console.wait(
        "() => document.querySelector('[data-test=ground-banner]').hidden",
        "the standby strip gone after the takeover",
        timeout_ms=30_000,
    )
    assert b.app.state.authority.status()["role"] == "holder"
