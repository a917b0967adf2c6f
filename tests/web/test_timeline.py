"""The timeline of contact windows and the live view's countdowns, in the browser
(docs/console.md, "Timeline and countdown").

The timeline must draw exactly the windows ``GET /api/windows`` returns (count, relay, AOS,
LOS, net time), on a time axis (each bar where its times put it), with the passes scheduled
in them placed in their window, by state, opening on a click; the live view must count down
to the pass's window's LOS and to the mission's next acquisition with the values the windows
give, on the ground's clock (the browser's clock is set 5 h wrong here: the console must not
count on it), and say plainly when a pass has no window.

No vehicle flies here: passes are scheduled over REST, and one is aborted while it is still
scheduled.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import httpx
import pytest

from mission import MISSIONS_DIR
from server.storage import repository as repo
from server.storage.db import sqlite_url
from tests.server.link.harness import OPERATOR, VIEWER, Ground, running_ground
from tests.server.storage.factories import make_plan
from tests.support.web import OPERATOR_TOKEN, VIEWER_TOKEN, Console

pytestmark = pytest.mark.realtime  # flies a vehicle or serves a live link in wall time

ETS7 = MISSIONS_DIR / "ets7-1999.toml"
START_1999 = "1999-09-30T00:00:00Z"
#: The timeline's layout (web/src/pages/timeline.ts): the lanes' labels, the right margin.
GUTTER_PX = 130
PAD_RIGHT_PX = 16
#: The browser's clock is set this far ahead of the ground's.
BROWSER_CLOCK_AHEAD = timedelta(hours=5)


def _ms(iso: str) -> int:
    """ms since the epoch of an ISO time, truncated as JavaScript's Date.parse does."""
    return int(datetime.fromisoformat(iso).timestamp() * 1000 // 1)


def _clock(seconds: float) -> str:
    """web/src/ui.ts ``clock``: m:ss or h:mm:ss of whole seconds (floored)."""
    s = int(abs(seconds) // 1)
    hours, rest = divmod(s, 3600)
    return f"{hours}:{rest // 60:02d}:{rest % 60:02d}" if hours else f"{rest // 60}:{rest % 60:02d}"


@pytest.fixture
def ground(tmp_path: Path) -> Iterator[Ground]:
    """The ground with, beside the shipped 1999 mission, ETS-VII's elements moved to this
    minute (``today``): its windows are around the ground's now; and the 1999 mission as
    ``short``: an AOS margin of 3000 s leaves each window 5 to 9 minutes of net time."""
    folder = tmp_path / "missions"
    folder.mkdir()
    epoch = datetime.now(UTC).replace(second=0, microsecond=0).strftime("%Y-%m-%dT%H:%M:%SZ")
    text = ETS7.read_text()
    moved = text.replace('epoch = "1999-09-30T00:00:00Z"', f'epoch = "{epoch}"')
    assert moved != text
    (folder / "today.toml").write_text(moved)
    short = text.replace("aos_margin_s = 120.0", "aos_margin_s = 3000.0")
    assert short != text
    (folder / "short.toml").write_text(short)
    with running_ground(sqlite_url(tmp_path), missions_dir=folder) as g:
        yield g


def _plan_id(ground: Ground, n_commands: int = 9) -> str:
    with ground.sessions() as session:
        plan = make_plan(n_commands=n_commands)
        plan_id = str(repo.add_plan(session=session, plan=plan, created_at_ns=0).id)
        session.commit()
        return plan_id


def _windows(ground: Ground, mission: str, start: str, hours: float) -> dict[str, Any]:
    response = httpx.get(
        f"{ground.url}/api/windows",
        params={"mission": mission, "start": start, "hours": hours},
        headers=VIEWER,
        timeout=60.0,
    )
    assert response.status_code == 200, response.text
    body: dict[str, Any] = response.json()
    return body


def _schedule(ground: Ground, body: dict[str, Any]) -> dict[str, Any]:
    response = httpx.post(f"{ground.url}/api/passes", json=body, headers=OPERATOR, timeout=60.0)
    assert response.status_code == 201, response.text
    scheduled: dict[str, Any] = response.json()
    return scheduled


def _in_window(ground: Ground, name: str, mission: str, window: dict[str, Any]) -> dict[str, Any]:
    return _schedule(
        ground,
        {
            "plan_id": _plan_id(ground),
            "name": name,
            "window": {
                "mission": mission,
                "relay": window["relay"],
                "aos_time": window["aos_time"],
            },
        },
    )


def test_an_operator_schedules_a_stored_plan_into_a_window_from_the_timeline(
    console: Console, ground: Ground
) -> None:
    """From a listed window's row: a stored plan too long for its net time is refused with
    the ground's message and code, nothing stored; a plan that fits is scheduled into that
    window (POST /api/passes naming it) and drawn in it."""
    hours = 6.0
    windows = _windows(ground, "short", START_1999, hours)["data"]
    third = windows[2]
    fits = _plan_id(ground)  # 2 s
    too_long = _plan_id(ground, n_commands=2400)  # 600 s
    assert 33.25 < third["net_s"] < 599.75
    page = console.page
    console.sign_in(OPERATOR_TOKEN, f"#/timeline/short/{START_1999}/{hours:g}")
    console.wait(
        f"() => document.querySelectorAll('[data-test=tl-window]').length === {len(windows)}",
        "the windows drawn",
    )
    page.click('[data-test=tl-schedule][data-index="2"]')
    title = page.text_content("[data-test=tl-schedule-title]") or ""
    assert title.startswith(f"Schedule a pass in {third['relay']}'s window: AOS 1999-09-30 ")
    page.wait_for_selector(f'[data-test=tl-plan] option[value="{too_long}"]', state="attached")
    page.select_option("[data-test=tl-plan]", too_long)
    page.fill("[data-test=tl-pass-name]", "from the timeline")
    page.click("[data-test=tl-schedule-submit]")
    console.wait(
        "() => document.querySelector('[data-test=tl-schedule-result]')?.dataset.code"
        " === 'plan_exceeds_window'",
        "the refusal shown",
    )
    refusal = page.text_content("[data-test=tl-schedule-result]") or ""
    assert refusal.startswith(f"plan {too_long} needs ")
    assert f"{third['relay']}'s window of mission short" in refusal
    assert refusal.endswith("(plan_exceeds_window)")
    listed = httpx.get(f"{ground.url}/api/passes", headers=VIEWER, timeout=60.0).json()
    assert listed["count"] == 0
    # the refusal is expected: the browser's two reports of it are not errors here
    deadline = time.monotonic() + 10.0
    while len(refused := [e for e in console.errors if "409" in e]) < 2:
        assert time.monotonic() < deadline, console.errors
        page.wait_for_timeout(50)
    assert f"HTTP 409 POST {ground.url}/api/passes" in refused, refused
    for e in refused:
        console.errors.remove(e)

    page.select_option("[data-test=tl-plan]", fits)
    page.click("[data-test=tl-schedule-submit]")
    console.wait(
        "() => document.querySelector('[data-test=tl-pass][data-name=\"from the timeline\"]')"
        "?.dataset.windowIndex === '2'",
        "the pass drawn in its window",
    )
    console.screenshot("timeline-scheduled")
    [scheduled] = httpx.get(f"{ground.url}/api/passes", headers=VIEWER, timeout=60.0).json()["data"]
    assert scheduled["name"] == "from the timeline" and scheduled["plan_id"] == fits
    assert scheduled["window"]["mission"] == "short"
    assert scheduled["window"]["relay"] == third["relay"]
    assert _ms(scheduled["window"]["aos_time"]) == _ms(third["aos_time"])
    assert _ms(scheduled["aos_time"]) == _ms(third["net_start_time"])
    assert _ms(scheduled["los_time"]) == _ms(third["net_end_time"])
    result = page.get_attribute("[data-test=tl-schedule-result]", "data-pass")
    assert result == scheduled["id"]
    row_pass = page.text_content('[data-test=tl-row][data-index="2"] [data-test=tl-row-pass]')
    assert row_pass == "from the timeline (scheduled)"


def test_the_timeline_shows_the_windows_the_api_returns_and_the_passes_in_them(
    console: Console, ground: Ground
) -> None:
    hours = 6.0
    api = _windows(ground, "ets7-1999", START_1999, hours)
    windows = api["data"]
    assert api["count"] == len(windows) == 7  # both relays, an orbit apart
    # A pass in the third window, and one given by hand in the span.
    third = windows[2]
    in_window = _in_window(ground, "campaign 1", "ets7-1999", third)
    by_hand = _schedule(
        ground,
        {
            "plan_id": _plan_id(ground),
            "name": "typed in",
            "aos_time": "1999-09-30T04:00:00Z",
            "los_time": "1999-09-30T04:30:00Z",
            "relay": "TDRS",
        },
    )
    page = console.page
    console.sign_in(VIEWER_TOKEN, f"#/timeline/ets7-1999/{START_1999}/{hours:g}")
    console.wait(
        f"() => document.querySelectorAll('[data-test=tl-window]').length === {len(windows)}"
        " && document.querySelectorAll('[data-test=tl-pass]').length === 2",
        "the windows and passes drawn",
    )
    assert page.get_attribute("[data-test=tl-summary]", "data-count") == str(len(windows))
    console.screenshot("timeline-1999")
    assert page.input_value("[data-test=tl-mission]") == "ets7-1999"

    drawn = page.eval_on_selector_all(
        "[data-test=tl-window]",
        """els => els.map(g => ({
            relay: g.dataset.relay, aos: g.dataset.aos, los: g.dataset.los,
            net_start: g.dataset.netStart, net_end: g.dataset.netEnd, passes: g.dataset.passes,
            aos_x: Number(g.querySelector('.mark.aos').getAttribute('x1')),
            los_x: Number(g.querySelector('.mark.los').getAttribute('x1')),
            bar_x: Number(g.querySelector('.bar').getAttribute('x')),
            bar_y: Number(g.querySelector('.bar').getAttribute('y')),
        }))""",
    )
    assert [(d["relay"], d["aos"], d["los"], d["net_start"], d["net_end"]) for d in drawn] == [
        (w["relay"], w["aos_time"], w["los_time"], w["net_start_time"], w["net_end_time"])
        for w in windows
    ]
    # On the time axis: each AOS and LOS mark where its time puts it (a LOS past the span
    # at its end), one lane per relay.
    width = float(page.get_attribute("[data-test=tl-svg]", "width") or 0)
    start_ms = _ms(START_1999)
    span_ms = hours * 3600_000
    plot_px = width - GUTTER_PX - PAD_RIGHT_PX

    def x(ms: int) -> float:
        return min(width - PAD_RIGHT_PX, GUTTER_PX + (ms - start_ms) / span_ms * plot_px)

    for d, w in zip(drawn, windows, strict=True):
        assert d["aos_x"] == pytest.approx(x(_ms(w["aos_time"])), abs=0.01)
        assert d["los_x"] == pytest.approx(x(_ms(w["los_time"])), abs=0.01)
    lanes = {w["relay"]: d["bar_y"] for d, w in zip(drawn, windows, strict=True)}
    assert sorted(lanes) == ["TDRS-East", "TDRS-West"] and len(set(lanes.values())) == 2
    assert page.eval_on_selector_all(
        "[data-test=tl-lane]", "els => els.map(e => e.textContent)"
    ) == ["TDRS-East", "TDRS-West", "given by hand"]
    # The table: a row per window, its times to the second.
    rows = page.eval_on_selector_all(
        "[data-test=tl-row]",
        "els => els.map(r => [r.dataset.relay, r.querySelector('[data-test=tl-aos]').textContent,"
        " r.querySelector('[data-test=tl-los]').textContent])",
    )
    assert rows == [
        [
            w["relay"],
            f"{w['aos_time'][:10]} {w['aos_time'][11:19]}Z",
            f"{w['los_time'][:10]} {w['los_time'][11:19]}Z",
        ]
        for w in windows
    ]

    # The passes: the windowed one in the third window, the typed one in the hand lane.
    passes = {
        p["name"]: p
        for p in page.eval_on_selector_all(
            "[data-test=tl-pass]",
            """els => els.map(a => ({name: a.dataset.name, id: a.dataset.pass,
                state: a.dataset.state, index: a.dataset.windowIndex, relay: a.dataset.relay,
                x: Number(a.querySelector('rect').getAttribute('x')),
                w: Number(a.querySelector('rect').getAttribute('width'))}))""",
        )
    }
    placed = passes["campaign 1"]
    assert placed["id"] == in_window["id"] and placed["state"] == "scheduled"
    assert placed["index"] == "2" and placed["relay"] == third["relay"]
    assert drawn[2]["passes"] == in_window["id"]
    assert [d["passes"] for i, d in enumerate(drawn) if i != 2] == [""] * (len(windows) - 1)
    # its bar is its net time, inside the window's AOS..LOS
    assert placed["x"] == pytest.approx(x(_ms(third["net_start_time"])), abs=0.01)
    assert placed["x"] + placed["w"] == pytest.approx(x(_ms(third["net_end_time"])), abs=0.01)
    assert drawn[2]["aos_x"] < placed["x"] < placed["x"] + placed["w"] < drawn[2]["los_x"]
    typed = passes["typed in"]
    assert typed["id"] == by_hand["id"] and typed["index"] == "" and typed["relay"] == ""
    assert typed["x"] == pytest.approx(x(_ms("1999-09-30T04:00:00+00:00")), abs=0.01)

    # Its state follows the pass: aborted while scheduled, redrawn from the pushed event.
    response = httpx.post(
        f"{ground.url}/api/passes/{in_window['id']}/abort",
        json={"confirm": "ABORT campaign 1", "reason": "test"},
        headers=OPERATOR,
        timeout=60.0,
    )
    assert response.status_code == 200, response.text
    console.wait(
        f"() => document.querySelector('[data-test=tl-pass][data-pass=\"{in_window['id']}\"]')"
        "?.dataset.state === 'aborted'",
        "the aborted state drawn",
    )

    # A click opens the pass; its window is long closed on the ground's clock, and the
    # 1999 elements do not reach today: said, not computed.
    page.click(f'[data-test=tl-pass][data-pass="{typed["id"]}"]')
    page.wait_for_selector("[data-test=pass-name]:has-text('typed in')")
    assert page.url.endswith(f"#/live/{typed['id']}")
    page.go_back()
    console.wait("() => document.querySelectorAll('[data-test=tl-window]').length === 7", "back")
    page.click(f'[data-test=tl-pass][data-pass="{in_window["id"]}"]')
    page.wait_for_selector("[data-test=pass-name]:has-text('campaign 1')")
    console.wait(
        "() => document.querySelector('[data-test=countdown]')?.dataset.clock === 'ground'"
        " && document.querySelector('[data-test=next-aos]')?.textContent.includes('elements')",
        "the countdown of a 1999 window",
    )
    countdown = page.eval_on_selector(
        "[data-test=countdown]", "e => ({...e.dataset, text: e.textContent})"
    )
    assert countdown["kind"] == "window" and countdown["phase"] == "after"
    assert int(countdown["targetMs"]) == _ms(third["los_time"])
    assert countdown["text"].startswith(f"{third['relay']} LOS ") and countdown["text"].endswith(
        " ago"
    )
    next_aos = page.text_content("[data-test=next-aos]") or ""
    assert next_aos.startswith(
        "Next AOS: not computed: ets7-1999's elements reach 1999-08-01 to 1999-11-29"
    )


def test_bad_span_is_refused_in_the_form_with_the_reason(console: Console, ground: Ground) -> None:
    console.sign_in(VIEWER_TOKEN, f"#/timeline/ets7-1999/{START_1999}/2")
    page = console.page
    console.wait(
        "() => document.querySelectorAll('[data-test=tl-window]').length > 0", "the windows"
    )
    page.fill("[data-test=tl-start]", "1999-09-30T00:00:00")  # no UTC offset
    page.click("[data-test=tl-show]")
    assert "is not an ISO 8601 time with its UTC offset" in (
        page.text_content("[data-test=tl-error]") or ""
    )
    page.fill("[data-test=tl-start]", "2005-01-01T00:00:00Z")
    page.click("[data-test=tl-show]")
    assert "ets7-1999's elements reach 1999-08-01 00:00:00Z to 1999-11-29 00:00:00Z" in (
        page.text_content("[data-test=tl-error]") or ""
    )
    page.click("[data-test=tl-epoch-button]")  # the elements' epoch
    assert page.input_value("[data-test=tl-start]") == START_1999
    page.fill("[data-test=tl-hours]", "500")
    page.click("[data-test=tl-show]")
    assert "Hours 500 is outside (0, 168]" in (page.text_content("[data-test=tl-error]") or "")
    # A good span draws again, and the address keeps it.
    page.fill("[data-test=tl-hours]", "24")
    page.click("[data-test=tl-show]")
    console.wait(
        "() => Number(document.querySelector('[data-test=tl-summary]')?.dataset.count) === 28",
        "a day of windows",
    )
    assert page.url.endswith(f"#/timeline/ets7-1999/{START_1999.replace(':', '%3A')}/24")


def test_the_live_countdown_counts_to_the_window_s_los_and_the_next_aos_on_the_ground_clock(
    console: Console, ground: Ground
) -> None:
    now = datetime.now(UTC)
    start = (now - timedelta(hours=2)).replace(second=0, microsecond=0)
    api = _windows(ground, "today", start.strftime("%Y-%m-%dT%H:%M:%SZ"), 30.0)["data"]
    # the window open now (or the next), with at least 15 minutes to its LOS
    now_ms = now.timestamp() * 1000
    window = next(w for w in api if _ms(w["los_time"]) > now_ms + 15 * 60_000)
    scheduled = _in_window(ground, "today's pass", "today", window)
    page = console.page
    page.clock.install(time=now + BROWSER_CLOCK_AHEAD)  # the browser's clock is wrong
    console.sign_in(VIEWER_TOKEN, f"#/live/{scheduled['id']}")
    console.wait(
        "() => document.querySelector('[data-test=countdown]')?.dataset.clock === 'ground'"
        " && document.querySelector('[data-test=next-aos]')?.dataset.kind === 'window'",
        "the countdowns on the ground clock",
    )
    console.screenshot("live-countdown")
    # One reading of both, rendered at the same instant.
    seen = page.evaluate(
        """() => {
            const c = document.querySelector('[data-test=countdown]');
            const n = document.querySelector('[data-test=next-aos]');
            const g = document.querySelector('[data-test=ground-clock]');
            return {c: {...c.dataset, text: c.textContent}, n: {...n.dataset, text: n.textContent},
                    g: g.dataset.clock, browser_ms: Date.now()};
        }"""
    )
    c, n = seen["c"], seen["n"]
    ground_ms = float(c["nowMs"])
    assert n["nowMs"] == c["nowMs"] and seen["g"] == "ground"
    # The ground's clock, not the browser's 5 h off (a generous guard, not a timing).
    assert abs(ground_ms - time.time() * 1000) < 60_000
    assert seen["browser_ms"] - ground_ms > BROWSER_CLOCK_AHEAD.total_seconds() * 1000 - 60_000
    # To the window's LOS while it is open, else to its AOS: the value against the window.
    aos_ms, los_ms = _ms(window["aos_time"]), _ms(window["los_time"])
    assert c["kind"] == "window"
    if aos_ms <= ground_ms:
        assert (c["phase"], c["target"], int(c["targetMs"])) == ("open", "los", los_ms)
        assert c["text"].startswith(
            f"{window['relay']} LOS in {_clock((los_ms - ground_ms) / 1000)}"
        )
        net_end_ms = _ms(scheduled["los_time"])
        assert f"net time ends in {_clock((net_end_ms - ground_ms) / 1000)}" in c["text"]
    else:
        assert (c["phase"], c["target"], int(c["targetMs"])) == ("before", "aos", aos_ms)
        assert c["text"] == f"{window['relay']} AOS in {_clock((aos_ms - ground_ms) / 1000)}"
    assert float(c["seconds"]) == pytest.approx((int(c["targetMs"]) - ground_ms) / 1000, abs=1e-3)
    # The next acquisition: the first window of the mission acquiring after now, any relay.
    following = min((w for w in api if _ms(w["aos_time"]) > ground_ms), key=lambda w: w["aos_time"])
    assert n["relay"] == following["relay"] and int(n["aosMs"]) == _ms(following["aos_time"])
    next_s = (_ms(following["aos_time"]) - ground_ms) / 1000
    assert float(n["seconds"]) == pytest.approx(next_s, abs=1e-3)
    assert n["text"].startswith(f"Next AOS: {following['relay']} in {_clock(next_s)} (")


def test_a_pass_given_by_hand_says_it_has_no_window(console: Console, ground: Ground) -> None:
    now = datetime.now(UTC)
    los = now + timedelta(minutes=40)
    scheduled = _schedule(
        ground,
        {
            "plan_id": _plan_id(ground),
            "name": "by hand",
            "aos_time": (now - timedelta(minutes=5)).isoformat(),
            "los_time": los.isoformat(),
        },
    )
    assert scheduled["window"] is None
    console.sign_in(VIEWER_TOKEN, f"#/live/{scheduled['id']}")
    console.wait(
        "() => document.querySelector('[data-test=countdown]')?.dataset.clock === 'ground'",
        "the countdown on the ground clock",
    )
    page = console.page
    c = page.eval_on_selector("[data-test=countdown]", "e => ({...e.dataset, text: e.textContent})")
    assert (c["kind"], c["phase"], c["target"]) == ("hand", "open", "los")
    assert int(c["targetMs"]) == _ms(scheduled["los_time"])
    remaining = (int(c["targetMs"]) - float(c["nowMs"])) / 1000
    assert c["text"] == (
        "No computed window: a pass given by hand (AOS/LOS typed in) · "
        f"typed LOS in {_clock(remaining)}"
    )
    assert page.text_content("[data-test=next-aos]") == (
        "Next AOS: no mission to compute it from (a pass given by hand)"
    )
