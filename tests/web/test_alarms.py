"""Alarms on the console, in the browser, against the real ground service: the banner's counts
when frames cross their bands, the plot of the alarming joint marked, an operator's
acknowledgement from the alarm list (recorded by the server), a viewer's disabled one, and
the pass state ``safed`` with its reason.

The vehicle is a connection on the link's websocket that says ``hello`` and sends the frames
a test makes (ETS-VII's nominal frames, a joint measured off its target: what the ground's
tracking-error check sees), so each band is crossed by a frame the test chose.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator
from typing import Any

import httpx
import pytest
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import ClientConnection, connect

from planner.limits import Severity
from server.storage import repository as repo
from telemetry.wire import Hello, Safing, SafingTrigger, TelemetryFrame, TelemetryMsg, encode
from tests.server.alarms.rig import T0_NS, TRACKING, bands, frame, value_in
from tests.server.link.harness import (
    OPERATOR,
    VIEWER,
    Ground,
    add_plan_and_pass,
    pass_state,
    store_pass,
)
from tests.server.storage.factories import make_plan
from tests.support.web import OPERATOR_TOKEN, VIEWER_TOKEN, Console

pytestmark = pytest.mark.realtime  # flies a vehicle or serves a live link in wall time

#: The banner's severities, worst first.
WORST_FIRST = ["severe", "critical", "distress", "warning", "watch"]


class WireVehicle:
    """A vehicle on the link's websocket: ``hello`` at :data:`T0_NS` onboard, then the frames
    and safing reports a test sends; what the ground sends it is read by a thread of its own,
    which answers a ``safe_exit`` as the vehicle does (``safing`` back to ``nominal`` with its
    ``request_id``) once the test has made it safe."""

    def __init__(self, ws: ClientConnection) -> None:
        self.ws = ws
        self.received: list[str] = []
        self.safe_since_ns: int | None = None
        self._reader = threading.Thread(target=self._read, name="wire-vehicle", daemon=True)
        self._reader.start()
        hello = Hello(
            vehicle="ETS-VII", onboard_time_ns=T0_NS, time_scale=1.0, next_telemetry_seq=0
        )
        self.ws.send(encode(hello))

    def _read(self) -> None:
        try:
            for message in self.ws:
                self.received.append(str(message))
                doc = json.loads(message)
                if doc.get("type") == "safe_exit" and self.safe_since_ns is not None:
                    report = Safing(
                        state="nominal",
                        since_time_ns=self.safe_since_ns,
                        exit_request_id=doc["request_id"],
                        onboard_time_ns=self.safe_since_ns + 10**9,
                    )
                    self.safe_since_ns = None
                    self.ws.send(encode(report))
        except ConnectionClosed:
            return

    def send(self, *frames: TelemetryFrame) -> None:
        self.ws.send(encode(TelemetryMsg(frames=list(frames))))

    def safe(self, trigger: SafingTrigger, cancelled: int) -> None:
        """Enter SAFE on this trigger (the report the vehicle downlinks at that tick)."""
        since = T0_NS + 10**9
        self.safe_since_ns = since
        report = Safing(
            state="safe",
            since_time_ns=since,
            trigger=trigger,
            cancelled=cancelled,
            onboard_time_ns=since,
        )
        self.ws.send(encode(report))

    def close(self) -> None:
        self.ws.close()
        self._reader.join(timeout=10.0)


@pytest.fixture
def vehicle(ground: Ground) -> Iterator[WireVehicle]:
    auth = {"Authorization": "Bearer s-token"}
    with connect(ground.ws_url, additional_headers=auth) as ws:
        craft = WireVehicle(ws)
        try:
            yield craft
        finally:
            craft.close()


def _scheduled_pass(ground: Ground, name: str) -> str:
    """A pass of a small ETS-VII plan whose telemetry window takes every frame (as the link
    opens it for a running pass): its frames are stored and checked as they come."""
    pass_id = add_plan_and_pass(
        ground.sessions, make_plan(9), name, now_ns=time.time_ns(), window_s=3600.0
    )
    ground.app.state.downlink.open_window(pass_id, 0)
    return pass_id


def _alarms(ground: Ground, pass_id: str) -> list[dict[str, Any]]:
    reply = httpx.get(f"{ground.url}/api/alarms", params={"pass": pass_id}, headers=VIEWER)
    assert reply.status_code == 200, reply.text
    alarms: list[dict[str, Any]] = reply.json()["alarms"]
    return alarms


def _wait_alarms(ground: Ground, pass_id: str, ok: Any, what: str) -> list[dict[str, Any]]:
    deadline = time.monotonic() + 20.0
    while not ok(alarms := _alarms(ground, pass_id)):
        assert time.monotonic() < deadline, f"{what}: {alarms}"
        time.sleep(0.05)
    return alarms


def _banner(page: Any) -> dict[str, int]:
    counts: dict[str, int] = page.evaluate(
        "() => Object.fromEntries([...document.querySelectorAll("
        "'[data-test=alarm-summary] [data-severity]')].map(e => [e.dataset.severity,"
        " Number(e.dataset.count)]))"
    )
    return counts


def _wait_banner(console: Console, expected: dict[str, int], what: str) -> None:
    checks = " && ".join(
        f"document.querySelector('[data-test=alarm-summary] [data-severity={s}]')"
        f"?.dataset.count === '{expected.get(s, 0)}'"
        for s in WORST_FIRST
    )
    console.wait(f"() => {checks}", what)


def _row(page: Any, channel: str) -> Any:
    return page.locator(f"[data-test=alarms] tr[data-channel={channel}]")


def test_banner_counts_plot_marks_and_acknowledgement(
    console: Console, ground: Ground, vehicle: WireVehicle, browser: Any
) -> None:
    pass_id = _scheduled_pass(ground, "web-alarms")
    page = console.page
    console.sign_in(OPERATOR_TOKEN, f"#/live/{pass_id}")
    console.wait(
        "() => document.querySelector('[data-test=alarm-summary]')?.dataset.loaded === 'true'",
        "alarms loaded",
    )
    assert _banner(page) == dict.fromkeys(WORST_FIRST, 0)

    # Joint 2 into its warning band, joint 3 past its red (critical) limit, in one frame.
    warning = value_in(TRACKING, Severity.WARNING)
    critical = value_in(TRACKING, Severity.CRITICAL)
    vehicle.send(frame(0), frame(1, {1: warning, 2: critical}))
    _wait_banner(console, {"critical": 1, "warning": 1}, "banner counts the two alarms")
    order = page.evaluate(
        "() => [...document.querySelectorAll('[data-test=alarm-summary] [data-severity]')]"
        ".map(e => e.dataset.severity)"
    )
    assert order == WORST_FIRST
    summary = page.locator("[data-test=alarm-summary]")
    assert summary.get_attribute("data-worst") == "critical"
    assert page.text_content("[data-test=alarm-unacked]") == "2 unacknowledged"

    # The live view marks the joints in alarm on their plots, the worst severity's colour.
    console.wait(
        "() => document.querySelectorAll('[data-test=joint-plots] .plot.in-alarm').length === 2",
        "joint plots marked",
    )
    marked = page.evaluate(
        "() => [...document.querySelectorAll('[data-test=joint-plots] .plot')]"
        ".map(p => [p.dataset.alarmSeverity || null, p.dataset.alarmChannels || null,"
        " p.querySelector('.alarm-tag').hidden ? null : p.querySelector('.alarm-tag').textContent])"
    )
    assert [m[:2] for m in marked] == [
        [None, None],
        ["warning", "joint2"],
        ["critical", "joint3"],
        [None, None],
        [None, None],
        [None, None],
    ]
    limit = bands(TRACKING).threshold(Severity.CRITICAL)
    assert limit is not None
    assert marked[2][2] == f"CRITICAL joint3: {critical:.2f} deg ≥ {limit:.2f} deg"
    assert marked[1][2].startswith("WARNING joint2: ")
    console.screenshot("alarms-live-marked")

    # The banner opens the list: a row per alarm, values and limits in their units.
    summary.click()
    page.wait_for_function("() => location.hash === '#/alarms'")
    console.wait(
        "() => document.querySelector('[data-test=alarms]')?.dataset.count === '2'", "list"
    )
    row3 = _row(page, "joint3")
    assert row3.get_attribute("data-severity") == "critical"
    assert row3.locator("[data-test=state]").text_content() == "TRIGGERED"
    assert row3.locator("[data-test=limit]").text_content() == f"≥ {limit:.2f} deg"
    assert row3.locator("[data-test=worst]").text_content() == f"{critical:.2f} deg"
    assert row3.locator("[data-test=count]").text_content() == "1"

    # Back within limits: both clear, and stay listed (latching) until acknowledged.
    vehicle.send(frame(2))
    console.wait(
        "() => [...document.querySelectorAll('[data-test=alarms] tr[data-state]')]"
        ".every(r => r.dataset.state === 'cleared')",
        "both cleared",
    )
    assert _banner(page) == {**dict.fromkeys(WORST_FIRST, 0), "critical": 1, "warning": 1}

    # The operator acknowledges joint 3's alarm with a comment: the server records it,
    # the row says who, and the banner no longer counts it.
    row3.locator("[data-test=acknowledge]").click()
    page.fill("[data-test=ack-comment-input]", "joint 3 checked: test frame")
    page.click("[data-test=ack-go]")
    page.wait_for_selector(".backdrop", state="detached")
    [acked] = [a for a in _alarms(ground, pass_id) if a["channel"] == "joint3"]
    assert (acked["acknowledged"], acked["acknowledged_by"], acked["comment"]) == (
        True,
        "otto",
        "joint 3 checked: test frame",
    )
    _wait_banner(console, {"warning": 1}, "the acknowledged alarm leaves the banner")
    assert page.text_content("[data-test=alarm-unacked]") == "1 unacknowledged"
    # cleared and acknowledged: gone from the active list, still in "all"
    console.wait(
        "() => document.querySelector('[data-test=alarms]').dataset.count === '1'",
        "active list without it",
    )
    page.select_option("[data-test=alarms-which]", "all")
    console.wait(
        "() => document.querySelector('[data-test=alarms]')?.dataset.count === '2'"
        " && document.querySelector('tr[data-channel=joint3] [data-test=ack-comment]')",
        "all alarms, with the acknowledgement",
    )
    ack_text = _row(page, "joint3").locator("[data-test=ack]").text_content() or ""
    assert ack_text.startswith("otto at ") and "joint 3 checked: test frame" in ack_text
    console.screenshot("alarms-list-operator")

    # A viewer sees the same list, the action disabled with the reason.
    viewer = browser.new_context(viewport={"width": 1400, "height": 900})
    try:
        tab = Console(viewer.new_page(), ground.url)
        tab.page.on("pageerror", lambda e: tab.errors.append(f"page error: {e}"))
        tab.sign_in(VIEWER_TOKEN, "#/alarms")
        tab.wait(
            "() => document.querySelector('[data-test=alarms]')?.dataset.count === '1'",
            "viewer's list",
        )
        button = _row(tab.page, "joint2").locator("[data-test=acknowledge]")
        assert button.is_disabled()
        assert "operator role" in (button.get_attribute("title") or "")
        assert "operator role" in (tab.page.text_content("[data-test=viewer-note]") or "")
        tab.screenshot("alarms-list-viewer")
        assert tab.errors == []
    finally:
        viewer.close()
    # and the server refuses a viewer's forced acknowledgement anyway
    [joint2] = [a for a in _alarms(ground, pass_id) if a["channel"] == "joint2"]
    forced = httpx.post(
        f"{ground.url}/api/alarms/{joint2['id']}/acknowledge", json={}, headers=VIEWER
    )
    assert forced.status_code == 403
    [joint2] = [a for a in _alarms(ground, pass_id) if a["channel"] == "joint2"]
    assert joint2["acknowledged"] is False


def _link(ground: Ground) -> dict[str, Any]:
    status: dict[str, Any] = httpx.get(f"{ground.url}/api/link/status", headers=VIEWER).json()
    return status


def _wait_link(ground: Ground, ok: Any, what: str) -> dict[str, Any]:
    deadline = time.monotonic() + 20.0
    while not ok(status := _link(ground)):
        assert time.monotonic() < deadline, f"{what}: {status}"
        time.sleep(0.05)
    return status


def test_safed_pass_the_safe_banner_and_its_exit(
    console: Console, ground: Ground, vehicle: WireVehicle
) -> None:
    _wait_link(ground, lambda s: s["connected"], "the vehicle connects")
    pass_id = store_pass(ground.sessions, "web-safed", (4.0, 0.0, 0.0, 0.0, 0.0, 0.0), 60.0)
    other_id = store_pass(ground.sessions, "web-next", (2.0, 0.0, 0.0, 0.0, 0.0, 0.0), 5.0)
    started = httpx.post(
        f"{ground.url}/api/passes/{pass_id}/start",
        json={"confirm": "START web-safed"},
        headers=OPERATOR,
    )
    assert started.status_code == 200, started.text
    assert pass_state(ground, pass_id) == "running"

    # The vehicle safes itself on joint 3's tracking error: the ground ends the pass safed.
    trigger = SafingTrigger(
        quantity="joint_tracking_error_deg", channel="joint3", value=6.25, limit=5.0
    )
    vehicle.safe(trigger, cancelled=12)
    _wait_link(ground, lambda s: s.get("vehicle_mode") == "safe", "the ground hears SAFE")
    deadline = time.monotonic() + 20.0
    while pass_state(ground, pass_id) != "safed":
        assert time.monotonic() < deadline, pass_state(ground, pass_id)
        time.sleep(0.05)

    page = console.page
    console.sign_in(OPERATOR_TOKEN, "#/passes")
    # The SAFE strip on every page, with the trigger; the vehicle's critical alarm counted.
    page.wait_for_selector("[data-test=vehicle-safe]:not([hidden])")
    strip = page.text_content("[data-test=vehicle-safe]") or ""
    assert strip.startswith("VEHICLE SAFE (ETS-VII)") and "12 commands dropped" in strip, strip
    trigger_text = page.text_content("[data-test=safe-trigger]") or ""
    assert "joint_tracking_error_deg joint3 = 6.250 (limit 5.000)" in trigger_text
    _wait_banner(console, {"critical": 1}, "the vehicle's safing alarm")
    # The pass list: SAFED, with the reason the ground gave.
    row = page.locator(f"[data-pass='{pass_id}']")
    row.locator("[data-test=pass-state]").wait_for()
    assert row.locator("[data-test=pass-state]").text_content() == "SAFED"
    with ground.readers() as session:
        reason = repo.get_pass(session=session, pass_id=pass_id).state_reason
    assert reason and "joint3" in reason, reason
    assert row.locator("[data-test=state-reason]").text_content() == reason
    console.screenshot("safed-passes")
    # The live view too, and its controls: no start or abort of a safed pass.
    page.goto(f"{ground.url}/#/live/{pass_id}")
    console.wait(
        "() => document.querySelector('[data-test=pass-state]')?.textContent === 'SAFED'",
        "live view safed",
    )
    assert page.text_content("[data-test=state-reason]") == reason
    console.wait(
        "() => document.querySelector('[data-test=link-mode]')?.textContent === 'SAFE'",
        "the link panel says SAFE",
    )
    assert page.locator("[data-test=start], [data-test=abort]").count() == 0
    console.screenshot("safed-live")

    # Another pass cannot start while the vehicle is safe: the refusal, with its reason.
    page.goto(f"{ground.url}/#/live/{other_id}")
    page.click("[data-test=start]")
    page.fill("[data-test=confirm-input]", "web-next")
    page.click("[data-test=confirm-go]")
    page.wait_for_function(
        "() => document.querySelector('.dialog [role=alert]')?.textContent.includes('vehicle_safe')"
    )
    # leaving the page closes its dialog (it stayed open over the next page)
    page.evaluate("() => { location.hash = '#/passes'; }")
    page.wait_for_selector("div.backdrop", state="detached")
    assert page.locator("[role=dialog]").count() == 0
    assert pass_state(ground, other_id) == "scheduled"
    # the refusal is expected: the browser's two reports of it are not errors here
    deadline = time.monotonic() + 10.0
    while len(refused := [e for e in console.errors if "409" in e]) < 2:
        assert time.monotonic() < deadline, console.errors
        page.wait_for_timeout(50)
    assert len(refused) == 2 and any(e.startswith("HTTP 409 POST") for e in refused), refused
    for e in refused:
        console.errors.remove(e)

    # Exit SAFE from the banner: the vehicle's name typed; the ground sends the telecommand,
    # the vehicle answers nominal and the strip goes.
    page.click("[data-test=safe-exit]")
    go = page.locator("[data-test=confirm-go]")
    page.fill("[data-test=confirm-input]", "ETS-VI")
    assert go.is_disabled()
    page.fill("[data-test=confirm-input]", "ETS-VII")
    go.click()
    page.wait_for_selector(".backdrop", state="detached")
    page.wait_for_selector("[data-test=vehicle-safe]", state="hidden")
    assert _link(ground)["vehicle_mode"] == "nominal"
    assert any('"safe_exit"' in m for m in vehicle.received)
    assert pass_state(ground, pass_id) == "safed"  # the pass stays safed (terminal)
