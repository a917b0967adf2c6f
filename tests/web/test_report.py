"""After the pass: the report page overlays the flown archive on the prediction, says
plainly which server artefacts are not available, and replays the pass through the server's
replay over the console websocket (seek, play, pause, step; closed on leaving)."""

from __future__ import annotations

import bisect
import json
import time
from typing import Any

import httpx
import pytest

from tests.server.link.harness import OPERATOR, VIEWER, Ground, pass_state, store_pass
from tests.support.web import OPERATOR_TOKEN, Console, FlyingSpacecraft

pytestmark = pytest.mark.realtime  # flies a vehicle or serves a live link in wall time


def _fly_to_completion(ground: Ground, name: str) -> str:
    pass_id = store_pass(ground.sessions, name, (5.0, 0.0, 0.0, 0.0, 0.0, 0.0), 5.0)
    deadline = time.monotonic() + 20.0
    while not httpx.get(f"{ground.url}/api/link/status", headers=VIEWER).json()["connected"]:
        assert time.monotonic() < deadline, "the spacecraft did not connect"
        time.sleep(0.05)
    response = httpx.post(
        f"{ground.url}/api/passes/{pass_id}/start",
        json={"confirm": f"START {name}"},
        headers=OPERATOR,
    )
    assert response.status_code == 200, response.text
    deadline = time.monotonic() + 90.0
    while pass_state(ground, pass_id) != "complete":
        assert time.monotonic() < deadline, "the pass did not complete"
        time.sleep(0.1)
    return pass_id


def _archive_times(ground: Ground, pass_id: str) -> list[int]:
    """The onboard times of the pass's archived frames, in order (REST)."""
    times: list[int] = []
    t0 = 0
    while True:
        page = httpx.get(
            f"{ground.url}/api/passes/{pass_id}/telemetry",
            params={"t0": t0, "limit": 10000, "fields": "j1"},
            headers=VIEWER,
        ).json()
        rows = page["rows"]
        times += [row["generation_time_ns"] for row in rows]
        if not page["truncated"] or not rows:
            return times
        t0 = rows[-1]["generation_time_ns"] + 1


def test_report_overlays_and_replays_a_flown_pass(
    console: Console, ground: Ground, flying: FlyingSpacecraft
) -> None:
    pass_id = _fly_to_completion(ground, "web-report")
    flying.stop()  # every frame drained to the ground: the archive stops growing
    times = _archive_times(ground, pass_id)
    deadline = time.monotonic() + 10.0
    while True:
        time.sleep(0.3)
        again = _archive_times(ground, pass_id)
        if again == times:
            break
        assert time.monotonic() < deadline, "the archive did not settle"
        times = again
    page = console.page
    sent: list[dict[str, Any]] = []
    received: list[dict[str, Any]] = []

    def watch(ws: Any) -> None:
        if ws.url.endswith("/api/console"):
            ws.on("framesent", lambda payload: sent.append(json.loads(payload)))
            ws.on("framereceived", lambda payload: received.append(json.loads(payload)))

    page.on("websocket", watch)
    console.sign_in(OPERATOR_TOKEN, f"#/report/{pass_id}")
    console.wait("() => document.querySelector('main').dataset.frames", "archive loaded")
    page.wait_for_selector("[data-test=replay-play]:not([disabled])")
    data = "document.querySelector('main').dataset"

    def dataset() -> dict[str, str]:
        return dict(page.evaluate(f"() => ({{...{data}}})"))

    def points() -> int:
        return int(
            page.evaluate(
                "() => Number(document.querySelector('[data-test=joint-plots] .plot')"
                ".dataset.points)"
            )
        )

    frames = int(dataset()["frames"])
    assert frames > 50
    # the outcome the summary gives: every command executed at its tag
    outcome = page.locator("[data-test=pass-outcome]")
    assert outcome.get_attribute("data-outcome") == "nominal"
    summary = httpx.get(f"{ground.url}/api/passes/{pass_id}/summary", headers=VIEWER).json()
    assert outcome.text_content() == "NOMINAL " + summary["outcome_text"].removeprefix("nominal: ")
    assert frames == len(times)
    assert points() == frames  # every archived frame is on the plot (the overlay)
    openapi = httpx.get(f"{ground.url}/openapi.json").json()["paths"]
    for suffix in ("report", "report.html", "recording.mcap"):
        offered = f"/api/passes/{{pass_id}}/{suffix}" in openapi
        selector = f"[data-test='{'get' if offered else 'na'}-{suffix}']"
        assert page.locator(selector).count() == 1, selector

    # The server's replay opened, paused at its first frame.
    opened = dataset()
    replay_id = opened["replayId"]
    assert replay_id.startswith("r-")
    assert opened["replayPosition"] == "0"
    assert int(opened["replayFrames"]) == frames
    assert int(opened["replayFirstNs"]) == times[0]
    assert int(opened["replayLastNs"]) == times[-1]

    # Seek to the middle: the server puts the replay on the first frame at or after the time,
    # and the plots restart with the archive before it.
    page.eval_on_selector(
        "[data-test=replay-scrub]",
        "el => { el.value = '500'; el.dispatchEvent(new Event('input')); }",
    )
    console.wait(f"() => {data}.replaySeeks === '1'", "the seek answered")
    state = dataset()
    target = int(state["replaySeekNs"])
    expected = bisect.bisect_left(times, target)
    assert 0 < expected < frames
    assert int(state["replayPosition"]) == expected
    assert int(state["replayNextNs"]) == times[expected]
    assert [m["onboard_time_ns"] for m in sent if m["type"] == "replay_seek"] == [target]
    console.wait(f"() => {data}.replayShown === '{expected}'", "the plots restarted")
    assert points() == expected
    seek_t = float(state["replayT"])

    # Play: frames come through the websocket replay, from the seek point on; pause.
    page.click("[data-test=replay-play]")
    console.wait(f"() => Number({data}.replayLastRow) >= {expected + 5}", "replayed frames arrived")
    page.click("[data-test=replay-play]")
    console.wait(f"() => {data}.replayReason === 'pause'", "the pause answered")
    state = dataset()
    assert state["replaying"] == "false"
    assert int(state["replayFirstRow"]) == expected
    position = int(state["replayPosition"])
    assert position == int(state["replayLastRow"]) + 1  # all sent before the pause came
    assert int(state["replayReceived"]) == position - expected
    assert float(state["replayT"]) > seek_t
    console.wait(f"() => {data}.replayShown === '{position}'", "the plots caught up")
    assert points() == position
    replayed = [m for m in received if m.get("topic") == "replay" and m["type"] == "telemetry"]
    assert replayed and all(m["replay_id"] == replay_id for m in replayed)
    assert sum(m["count"] for m in replayed) == position - expected
    assert not any(m.get("topic") == "telemetry" for m in received)  # no live data here

    # Step by step: one frame per step.
    page.select_option("[data-test=replay-speed]", "step")
    console.wait(f"() => {data}.replayReason === 'speed'", "the speed answered")
    page.click("[data-test=replay-step]")
    console.wait(f"() => {data}.replayReason === 'step'", "the step answered")
    state = dataset()
    assert int(state["replayPosition"]) == position + 1
    assert int(state["replayLastRow"]) == position
    console.screenshot("report")

    # Leaving the page closes the replay.
    page.evaluate("() => { location.hash = '#/passes'; }")
    deadline = time.monotonic() + 10.0
    while not any(m["type"] == "replay_closed" for m in received):
        assert time.monotonic() < deadline, "the replay was not closed"
        page.wait_for_timeout(50)
    assert [m["replay_id"] for m in sent if m["type"] == "replay_close"] == [replay_id]
    page.evaluate(f"() => {{ location.hash = '#/report/{pass_id}'; }}")
    page.wait_for_selector("[data-test=replay-play]:not([disabled])")

    # The server's analyses, when this server offers them: an operator runs them here.
    if "/api/passes/{pass_id}/analyses" in openapi:
        page.click("[data-test=run-analyses]")
        page.wait_for_selector("[data-test=report-tables] table", timeout=120_000)
        console.screenshot("report-analysed")
