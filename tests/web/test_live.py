"""The live pass view and commanding, in the browser, while a pass flies at 20x.

What a flight controller relies on: the link shows connected, the plots fill as telemetry
streams (point counts grow), command stages appear, the onboard schedule shows how far ahead
the uplink has loaded it, an operator starts and aborts with the pass name typed (the
commands the abort cancels show as such), and a viewer sees the same pages without the
controls (the server refuses a forced request with 403 anyway).
"""

from __future__ import annotations

import re
import time
from typing import TYPE_CHECKING, Any

import httpx
import pytest

from server.storage import repository as repo
from tests.server.link.harness import VIEWER, Ground, add_plan_and_pass, pass_state, store_pass
from tests.server.link.long_pass import long_plan
from tests.support.web import OPERATOR_TOKEN, VIEWER_TOKEN, Console, FlyingSpacecraft

if TYPE_CHECKING:
    from tests.support.made_once import MadeOnce

pytestmark = pytest.mark.realtime  # flies a vehicle or serves a live link in wall time


def _wait_connected(ground: Ground) -> None:
    deadline = time.monotonic() + 20.0
    while not httpx.get(f"{ground.url}/api/link/status", headers=VIEWER).json()["connected"]:
        assert time.monotonic() < deadline, "the spacecraft did not connect"
        time.sleep(0.05)


def _points(page: Any) -> list[int]:
    counts: list[int] = page.evaluate("() => window.hikoboshiLive.pointCounts()")
    return counts


def _value(page: Any, test: str) -> float:
    """The number a gauge or uplink row of the live view shows (its ``data-value``)."""
    value = page.get_attribute(f"[data-test={test}]", "data-value")
    assert value not in (None, ""), f"{test} shows no number"
    return float(value)


def _confirm(page: Any, name: str, button: str) -> None:
    page.click(f"[data-test={button}]")
    go = page.locator("[data-test=confirm-go]")
    page.fill("[data-test=confirm-input]", name[:-1])  # not yet the name: still refused
    assert go.is_disabled()
    page.fill("[data-test=confirm-input]", name)
    go.click()
    page.wait_for_selector(".backdrop", state="detached")


def test_operator_starts_watches_and_aborts_a_pass(
    console: Console, ground: Ground, flying: FlyingSpacecraft, made_once: MadeOnce
) -> None:
    # A long settle keeps the pass running while the test looks at it (400 s onboard = 40 s
    # at 10x): tests/server/link/long_pass.py's plan, planned once per run.
    pass_id = add_plan_and_pass(
        ground.sessions, long_plan(made_once), "web-live", now_ns=time.time_ns(), window_s=1200.0
    )
    _wait_connected(ground)
    page = console.page
    console.sign_in(OPERATOR_TOKEN, f"#/live/{pass_id}")
    assert page.text_content("[data-test=role]") == "operator"
    page.wait_for_function(
        "() => document.querySelector('[data-test=link-connected]')"
        "?.textContent.startsWith('connected')"
    )
    assert page.text_content("[data-test=pass-state]") == "SCHEDULED"

    _confirm(page, "web-live", "start")
    page.wait_for_function(
        "() => document.querySelector('[data-test=pass-state]').textContent === 'RUNNING'"
    )
    # The plots fill: every plot gains points, and keeps gaining them.
    console.wait("() => Math.min(...window.hikoboshiLive.pointCounts()) > 30", "plots fill")
    first = _points(page)
    console.wait(
        f"() => window.hikoboshiLive.pointCounts().every((n, i) => n > {first}[i] + 30)",
        "plots keep filling",
    )
    # Command stages arrive: executed commands counted on the timeline.
    console.wait(
        "() => Number(document.querySelector('[data-stage=executed]')?.dataset.count) > 5",
        "commands executed",
    )
    assert page.is_hidden("[data-test=stale]")
    # The schedule gauge: the uplink keeps the vehicle's schedule loaded up to the lead
    # window (120 s, 4 Hz: about 480 commands) ahead; numbers from the running pass.
    console.wait(
        "() => Number(document.querySelector('[data-test=schedule-lead]')?.dataset.value) > 60"
        " && document.querySelector('[data-test=uplink-margin]')?.dataset.value",
        "schedule loaded ahead",
    )
    queued_text = page.text_content("[data-test=schedule-queued]") or ""
    match = re.fullmatch(r"schedule: (\d+)/(\d+) queued", queued_text)
    assert match is not None, queued_text
    assert int(match[2]) == 1024  # the vehicle's default capacity, from its frames
    assert 200 < int(match[1]) <= 4 * 125, queued_text  # a lead window's worth, not the pass
    lead_s = _value(page, "schedule-lead")
    assert 60 < lead_s < 125, lead_s  # within the window (and the clock estimate's slack)
    assert "(lead window 120 s)" in (page.text_content("[data-test=schedule-lead]") or "")
    assert _value(page, "uplink-sent") >= int(match[1])
    assert _value(page, "uplink-retx") >= 0
    # Every command reached the vehicle ahead of its tag by more than the ground's bound
    # (one-way delay + half the margin when sent, less the delay on the way: 1 s).
    assert _value(page, "uplink-margin") > 1.0
    rtt = page.text_content("[data-test=link-rtt]")
    assert rtt is not None and rtt.endswith(" s")
    console.screenshot("live-operator-running")

    # The spacecraft goes quiet: within seconds the view says the data is stale.
    flying.stop()
    console.wait(
        "() => !document.querySelector('[data-test=stale]').hidden"
        " && document.querySelector('[data-test=values]').classList.contains('is-stale')",
        "stale badge",
    )
    assert page.text_content("[data-test=stale]").startswith("STALE")
    console.wait(
        "() => document.querySelector('[data-test=link-connected]').textContent"
        " === 'NOT CONNECTED'",
        "link shows disconnected",
    )
    console.screenshot("live-operator-stale")

    _confirm(page, "web-live", "abort")
    page.wait_for_function(
        "() => document.querySelector('[data-test=pass-state]').textContent === 'ABORTED'"
    )
    assert pass_state(ground, pass_id) == "aborted"
    with ground.sessions() as session:
        events = repo.list_events(session=session, pass_id=pass_id, kinds=["pass_state"]).items
    assert [(e.detail["to"], e.actor) for e in events][-1] == ("aborted", "otto")
    assert page.locator("[data-test=start], [data-test=abort]").count() == 0
    # With the link down the delete waits for it, but the commands beyond the lead window,
    # never sent, are cancelled at once: the timeline counts exactly the archive's.
    with ground.sessions() as session:
        commands = repo.list_commands(session=session, pass_id=pass_id)
    cancelled = sum(1 for c in commands if c.stage == "cancelled")
    assert cancelled > 0, "nothing cancelled: the pass should reach past the lead window"
    console.wait(
        "() => Number(document.querySelector('[data-stage=cancelled]')?.dataset.count)"
        f" === {cancelled}",
        "cancelled counted",
    )
    note = page.text_content("[data-test=cancel-note]") or ""
    assert note.startswith(f"cancelled {cancelled} (seq ") and "operator abort" in note, note
    console.screenshot("live-operator-aborted")


def test_viewer_sees_the_pass_without_controls(console: Console, ground: Ground) -> None:
    pass_id = store_pass(ground.sessions, "web-view", (4.0, 0.0, 0.0, 0.0, 0.0, 0.0), 5.0)
    page = console.page
    console.sign_in(VIEWER_TOKEN, f"#/live/{pass_id}")
    assert page.text_content("[data-test=role]") == "viewer"
    page.wait_for_function(
        "() => document.querySelector('[data-test=pass-state]')?.textContent === 'SCHEDULED'"
    )
    page.wait_for_selector("[data-test=link-connected]")
    assert page.locator("[data-test=start], [data-test=abort]").count() == 0
    console.screenshot("live-viewer")

    page.goto(f"{ground.url}/#/passes")
    page.wait_for_selector(f"[data-pass='{pass_id}']")
    assert page.locator("[data-test=start], [data-test=abort]").count() == 0
    console.screenshot("passes-viewer")

    # Forced: the server refuses a viewer's start whatever the page shows.
    response = page.request.post(
        f"{ground.url}/api/passes/{pass_id}/start",
        data={"confirm": "START web-view"},
        headers={"Authorization": f"Bearer {VIEWER_TOKEN}"},
    )
    assert response.status == 403
    assert response.json()["error"]["code"] == "forbidden"
    assert pass_state(ground, pass_id) == "scheduled"


def test_a_refused_token_stays_on_the_sign_in(console: Console) -> None:
    page = console.page
    page.goto(console.base_url)
    page.fill("[data-test=token]", "not-a-token")
    page.click("[data-test=signin]")
    page.wait_for_function(
        "() => document.querySelector('[data-test=signin-error]').textContent.includes('unknown')"
    )
    assert page.evaluate("() => sessionStorage.getItem('hikoboshi.token')") is None
