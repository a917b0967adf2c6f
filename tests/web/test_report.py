"""After the pass: the report page overlays the flown archive on the prediction, says
plainly which server artefacts are not available, and replays the pass (play and seek)."""

from __future__ import annotations

import time

import httpx

from tests.server.link.harness import OPERATOR, VIEWER, Ground, pass_state, store_pass
from tests.web.conftest import OPERATOR_TOKEN, Console, FlyingSpacecraft


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


def test_report_overlays_and_replays_a_flown_pass(
    console: Console, ground: Ground, flying: FlyingSpacecraft
) -> None:
    pass_id = _fly_to_completion(ground, "web-report")
    page = console.page
    console.sign_in(OPERATOR_TOKEN, f"#/report/{pass_id}")
    page.wait_for_selector("[data-test=replay-play]:not([disabled])")
    frames = int(page.evaluate("() => document.querySelector('main').dataset.frames"))
    assert frames > 50
    points = page.evaluate(
        "() => Number(document.querySelector('[data-test=joint-plots] .plot').dataset.points)"
    )
    assert points == frames  # every archived frame is on the plot
    openapi = httpx.get(f"{ground.url}/openapi.json").json()["paths"]
    for suffix in ("report", "report.html", "recording.mcap"):
        offered = f"/api/passes/{{pass_id}}/{suffix}" in openapi
        selector = f"[data-test='{'get' if offered else 'na'}-{suffix}']"
        assert page.locator(selector).count() == 1, selector

    # Seek: the replay time follows the slider; play: it advances by itself.
    page.eval_on_selector(
        "[data-test=replay-scrub]",
        "el => { el.value = '500'; el.dispatchEvent(new Event('input')); }",
    )
    middle = float(page.evaluate("() => document.querySelector('main').dataset.replayT"))
    page.eval_on_selector(
        "[data-test=replay-scrub]",
        "el => { el.value = '100'; el.dispatchEvent(new Event('input')); }",
    )
    early = float(page.evaluate("() => document.querySelector('main').dataset.replayT"))
    assert early < middle
    page.click("[data-test=replay-play]")
    page.wait_for_function(
        f"() => Number(document.querySelector('main').dataset.replayT) > {early} + 1"
    )
    page.click("[data-test=replay-play]")
    console.screenshot("report")

    # The server's analyses, when this server offers them: an operator runs them here.
    if "/api/passes/{pass_id}/analyses" in openapi:
        page.click("[data-test=run-analyses]")
        page.wait_for_selector("[data-test=report-tables] table", timeout=120_000)
        console.screenshot("report-analysed")
