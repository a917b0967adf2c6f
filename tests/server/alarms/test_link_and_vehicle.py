"""The link's health on the ground's timer while a pass runs, the vehicle's safing alarm, and
alarms taken over by a restarted ground (simulated time; SQLite and PostgreSQL)."""

from __future__ import annotations

import asyncio
from typing import Any

import pytest

from planner.limits import Severity
from server.services.alarms import LINK_PERIOD_S, VEHICLE_SAFING
from telemetry.wire import Safing, SafingTrigger
from tests.server.alarms.rig import (
    PERIOD_NS,
    T0_NS,
    TRACKING,
    Rig,
    bands,
    end_pass,
    frame,
    run,
    start_pass,
    value_in,
)

W = Severity.WATCH


def _of(rig: Rig, quantity: str) -> list[dict[str, Any]]:
    return [a for a in rig.alarms() if a["quantity"] == quantity]


def test_frame_age_raises_while_the_pass_runs_and_clears(database_url: str) -> None:
    threshold = bands("frame_age_s").threshold(W)
    assert threshold is not None

    async def scenario(rig: Rig) -> None:
        await start_pass(rig, [])
        await rig.send(*(frame(s) for s in range(10)))
        received_s = rig.clock.monotonic()
        await rig.clock.advance(threshold + 2 * LINK_PERIOD_S, step=LINK_PERIOD_S)
        await rig.settled()
        [age] = _of(rig, "frame_age_s")
        assert (age["state"], age["severity"], age["source"]) == ("triggered", "watch", "limit")
        # raised by the first check at or past the threshold, on the ground's clock
        assert threshold <= age["trigger_value"] < threshold + LINK_PERIOD_S + 1e-6
        assert age["raised_frame_seq"] is None and age["pass_id"] == rig.pass_id
        waited_s = rig.clock.monotonic() - received_s
        seq = round(waited_s * 1e9 / PERIOD_NS)
        await rig.send(frame(seq))
        await rig.clock.advance(LINK_PERIOD_S)
        await rig.settled()
        [age] = _of(rig, "frame_age_s")
        assert age["state"] == "cleared" and age["last_value"] <= LINK_PERIOD_S
        # again without frames, then the pass ends: the link is no longer watched for it
        await rig.clock.advance(threshold + 2 * LINK_PERIOD_S, step=LINK_PERIOD_S)
        await rig.settled()
        assert _of(rig, "frame_age_s")[0]["state"] == "triggered"
        await end_pass(rig, "aborted")
        [age] = _of(rig, "frame_age_s")
        assert age["state"] == "cleared" and "no longer watched" in age["detail"]
        await rig.clock.advance(threshold + 2 * LINK_PERIOD_S, step=LINK_PERIOD_S)
        await rig.settled()
        assert _of(rig, "frame_age_s")[0]["state"] == "cleared"

    run(database_url, scenario)


def _safe(since_ns: int, now_ns: int) -> Safing:
    trigger = SafingTrigger(
        quantity="joint_tracking_error_deg", channel="joint3", value=6.25, limit=5.0
    )
    return Safing(state="safe", since_time_ns=since_ns, trigger=trigger, onboard_time_ns=now_ns)


def test_the_vehicle_safing_raises_a_critical_alarm(database_url: str) -> None:
    async def scenario(rig: Rig) -> None:
        alarms = rig.live.alarms
        since = T0_NS + 42 * PERIOD_NS
        alarms.vehicle_safed(rig.pass_id, _safe(since, since))
        await rig.settled()
        [alarm] = rig.alarms()
        assert (alarm["source"], alarm["quantity"], alarm["severity"]) == (
            "vehicle",
            VEHICLE_SAFING,
            "critical",
        )
        assert (alarm["state"], alarm["pass_id"]) == ("triggered", rig.pass_id)
        assert (alarm["trigger_value"], alarm["limit"], alarm["unit"]) == (6.25, 5.0, "deg")
        assert alarm["raised_generation_time_ns"] == since
        assert "joint_tracking_error_deg joint3" in alarm["detail"]
        [raised] = rig.events("alarm_raised")
        assert raised.detail["source"] == "vehicle" and raised.pass_id == rig.pass_id
        # the report every second while safe: the same alarm
        await rig.clock.advance(1.0)
        alarms.vehicle_safed(rig.pass_id, _safe(since, since + 10**9))
        await rig.clock.advance(1.0)
        await rig.settled()
        [alarm] = rig.alarms()
        assert alarm["count"] == 2 and len(rig.events("alarm_raised")) == 1
        exit_report = Safing(state="nominal", since_time_ns=since, onboard_time_ns=since + 9)
        alarms.vehicle_nominal(rig.pass_id, exit_report)
        await rig.settled()
        [alarm] = rig.alarms()
        assert (alarm["state"], alarm["current_severity"]) == ("cleared", None)
        assert rig.alarms(active=True) != []  # latched until acknowledged
        # safed with no pass running
        alarms.vehicle_safed(None, _safe(since + 10**10, since + 10**10))
        await rig.settled()
        assert [a["pass_id"] for a in rig.alarms(active=True)] == [None, rig.pass_id]

    run(database_url, scenario)


def test_a_restarted_ground_takes_over_the_listed_alarms(database_url: str) -> None:
    watch = value_in(TRACKING, W)

    async def main() -> None:
        first = Rig(database_url)
        await first.connect()
        await first.send(frame(0, {4: watch}), frame(1))  # raised and cleared, not acknowledged
        first.live.alarms.vehicle_safed(None, _safe(T0_NS, T0_NS))
        await first.settled()
        [vehicle] = [a for a in first.alarms() if a["source"] == "vehicle"]
        [limit] = [a for a in first.alarms() if a["source"] == "limit"]
        await first.close()

        second = Rig(database_url, pass_id=first.pass_id)
        await second.connect()
        try:
            await second.send(frame(2, {4: watch}))
            second.live.alarms.vehicle_safed(None, _safe(T0_NS, T0_NS + 10**9))
            await second.settled()
            assert {a["id"] for a in second.alarms()} == {vehicle["id"], limit["id"]}
            again = next(a for a in second.alarms() if a["id"] == limit["id"])
            assert again["state"] == "triggered"
            assert [e["severity"] for e in again["timeline"]] == ["watch", None, "watch"]
        finally:
            await second.close()

    asyncio.run(main())


@pytest.mark.parametrize("state", ["los", "safed"])
def test_link_alarms_clear_when_the_pass_stops_running(tmp_path: Any, state: str) -> None:
    """At LOS the pass's telemetry window closes: no frame of it comes any more, and its
    age is no longer a sign of a bad link (nor after the vehicle safed it)."""
    from server.storage.db import sqlite_url

    threshold = bands("frame_age_s").threshold(W)
    assert threshold is not None

    async def scenario(rig: Rig) -> None:
        await start_pass(rig, [])
        await rig.clock.advance(threshold + 2 * LINK_PERIOD_S, step=LINK_PERIOD_S)
        await rig.settled()
        assert _of(rig, "frame_age_s")[0]["state"] == "triggered"
        await end_pass(rig, state)
        assert _of(rig, "frame_age_s")[0]["state"] == "cleared"
        await rig.clock.advance(threshold + 2 * LINK_PERIOD_S, step=LINK_PERIOD_S)
        await rig.settled()
        assert _of(rig, "frame_age_s")[0]["state"] == "cleared"  # not watched any more

    run(sqlite_url(tmp_path), scenario)
