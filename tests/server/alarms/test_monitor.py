"""Frames checked against limits as the live downlink stores them: an alarm raised on the very
frame that crossed, escalated, cleared, latched until acknowledged, reopened, written at most
once a second while in its band; on SQLite and PostgreSQL, in simulated time."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from planner.limits import Severity
from server.services.alarm_writes import IN_BAND_PERIOD_S
from server.services.errors import ConflictError, NotFoundError
from tests.server.alarms.rig import (
    PERIOD_NS,
    T0_NS,
    TRACKING,
    Rig,
    bands,
    below,
    end_pass,
    frame,
    run,
    severities,
    start_pass,
    value_in,
)

W, A, C = Severity.WATCH, Severity.WARNING, Severity.CRITICAL


def test_a_crossing_raises_on_that_frame_escalates_and_clears(database_url: str) -> None:
    watch, warning, critical = (value_in(TRACKING, s) for s in (W, A, C))

    async def scenario(rig: Rig) -> None:
        # frames 0..4 nominal, joint 3 leaves its band at frame 5, in one message
        await rig.send(*(frame(s) for s in range(5)), frame(5, {2: watch}), frame(6, {2: watch}))
        [alarm] = rig.alarms()
        assert (alarm["quantity"], alarm["channel"], alarm["source"]) == (
            TRACKING,
            "joint3",
            "limit",
        )
        assert alarm["raised_frame_seq"] == 5
        assert alarm["raised_generation_time_ns"] == T0_NS + 5 * PERIOD_NS
        assert (alarm["severity"], alarm["current_severity"], alarm["state"]) == (
            "watch",
            "watch",
            "triggered",
        )
        assert alarm["trigger_value"] == pytest.approx(watch)
        assert alarm["limit"] == pytest.approx(bands(TRACKING).threshold(W))
        assert alarm["pass_id"] == rig.pass_id and not alarm["acknowledged"]
        # escalation: each band change is written at once, whatever the second
        await rig.send(frame(7, {2: warning}))
        await rig.send(frame(8, {2: critical}), frame(9, {2: critical * 1.1}))
        [alarm] = rig.alarms()
        assert severities(alarm) == ["watch", "warning", "critical"]
        assert alarm["timeline"][1]["frame_seq"] == 7
        assert alarm["timeline"][2]["generation_time_ns"] == T0_NS + 8 * PERIOD_NS
        assert (alarm["severity"], alarm["current_severity"]) == ("critical", "critical")
        assert alarm["limit"] == pytest.approx(bands(TRACKING).threshold(C))
        # back within limits
        await rig.send(frame(10, {2: below(TRACKING)}))
        [alarm] = rig.alarms()
        assert (alarm["state"], alarm["current_severity"], alarm["severity"]) == (
            "cleared",
            None,
            "critical",
        )
        assert severities(alarm) == ["watch", "warning", "critical", None]
        assert alarm["cleared_generation_time_ns"] == T0_NS + 10 * PERIOD_NS
        assert alarm["worst_value"] == pytest.approx(critical * 1.1)
        assert alarm["count"] == 5  # frames 5..9 in a band
        assert alarm["id"] == rig.published[-1]["id"]
        assert [p["current_severity"] for p in rig.published] == [
            "watch",
            "warning",
            "critical",
            None,
        ]
        raised = rig.events("alarm_raised")
        cleared = rig.events("alarm_cleared")
        assert [e.detail["frame_seq"] for e in raised] == [5]
        assert raised[0].detail["alarm_id"] == alarm["id"] == cleared[0].detail["alarm_id"]
        assert raised[0].pass_id == rig.pass_id

    run(database_url, scenario)


def test_latching_reopening_and_acknowledgement(database_url: str) -> None:
    watch = value_in(TRACKING, W)

    async def scenario(rig: Rig) -> None:
        alarms = rig.live.alarms
        await rig.send(frame(0, {0: watch}), frame(1))
        [first] = rig.alarms()
        assert first["state"] == "cleared"
        assert [a["id"] for a in rig.alarms(active=True)] == [first["id"]]  # latched
        # entering the band again while still listed: the same alarm, triggered again
        await rig.send(frame(2, {0: watch}))
        [again] = rig.alarms()
        assert again["id"] == first["id"]
        assert (again["state"], again["cleared_time_ns"]) == ("triggered", None)
        assert severities(again) == ["watch", None, "watch"]
        assert len(rig.events("alarm_raised")) == 2
        assert rig.events("alarm_raised")[1].detail["reopened"] is True
        # acknowledged while triggered: still active until it clears
        acked = await alarms.acknowledge(first["id"], "olga", "looking at joint 1")
        assert (acked.acknowledged, acked.acknowledged_by, acked.comment) == (
            True,
            "olga",
            "looking at joint 1",
        )
        assert rig.published[-1]["acknowledged"] is True
        with pytest.raises(ConflictError) as refused:
            await alarms.acknowledge(first["id"], "olga", None)
        assert refused.value.code == "already_acknowledged"
        with pytest.raises(NotFoundError) as unknown:
            await alarms.acknowledge("f" * 32, "olga", None)
        assert unknown.value.code == "alarm_not_found"
        assert len(rig.alarms(active=True)) == 1
        await rig.send(frame(3))
        assert rig.alarms(active=True) == []
        [done] = rig.alarms()
        assert (done["state"], done["acknowledged"]) == ("cleared", True)
        # cleared and acknowledged: a new crossing is a new alarm
        await rig.send(frame(4, {0: watch}))
        new = rig.alarms(active=True)
        assert len(new) == 1 and new[0]["id"] != first["id"]
        assert new[0]["raised_frame_seq"] == 4
        ack_events = rig.events("alarm_acknowledged")
        assert [(e.actor, e.detail["comment"]) for e in ack_events] == [
            ("olga", "looking at joint 1")
        ]

    run(database_url, scenario)


def test_in_band_updates_are_written_at_most_once_a_second(database_url: str) -> None:
    watch = value_in(TRACKING, W)

    async def scenario(rig: Rig) -> None:
        await rig.send(frame(0, {1: watch}))
        for seq in range(1, 6):  # the ground's clock does not move: one second not yet up
            await rig.send(frame(seq, {1: watch * (1 + seq / 100)}))
        [stored] = rig.alarms()
        assert stored["count"] == 1 and len(rig.published) == 1
        await rig.clock.advance(IN_BAND_PERIOD_S)
        await rig.settled()
        [stored] = rig.alarms()
        assert stored["count"] == 6
        assert stored["worst_value"] == pytest.approx(watch * 1.05)
        assert stored["last_value"] == pytest.approx(watch * 1.05)
        assert len(rig.published) == 2 and rig.published[-1]["count"] == 6
        assert severities(stored) == ["watch"]  # no change of band: nothing in the timeline

    run(database_url, scenario)


def test_no_alarm_when_limit_checking_is_off(database_url: str) -> None:
    async def scenario(rig: Rig) -> None:
        await rig.send(frame(0, {2: value_in(TRACKING, C)}))
        assert rig.alarms() == [] and rig.live.alarms.frames_evaluated == 0

    run(database_url, scenario, limit_checking=False)


def test_a_frame_older_than_the_newest_checked_is_not_checked_again(tmp_path: Any) -> None:
    from server.storage.db import sqlite_url

    async def scenario(rig: Rig) -> None:
        await rig.send(frame(5))
        await rig.send(frame(3, {2: value_in(TRACKING, C)}))  # a resent gap, after frame 5
        assert rig.alarms() == []
        assert (rig.live.alarms.frames_evaluated, rig.live.alarms.frames_late) == (1, 1)

    run(sqlite_url(tmp_path), scenario)


def test_tracking_is_against_the_commands_while_the_pass_runs(database_url: str) -> None:
    """The plan commands joint 1 to a ramp the vehicle's frames do not follow (their own
    targets agree with the measured joints): the ground sees the error against the plan,
    interpolated at each frame's time; once the pass is aborted, against the frames'."""
    watch = value_in(TRACKING, W)

    async def scenario(rig: Rig) -> None:
        up = [float(np.radians(2 * watch))] + [0.0] * 5
        # from 0 at frame 14 to 2 x watch (deg) at frame 16: watch at frame 15, half way
        ramp = [(T0_NS + 14 * PERIOD_NS, [0.0] * 6), (T0_NS + 16 * PERIOD_NS, up)]
        await start_pass(rig, ramp)
        await rig.send(*(frame(s) for s in range(0, 15)))
        assert rig.alarms() == []  # up to frame 14 the plan commands what the frames say
        await rig.send(*(frame(s) for s in range(15, 17)))
        [alarm] = rig.alarms()
        assert (alarm["channel"], alarm["raised_frame_seq"]) == ("joint1", 15)
        assert alarm["trigger_value"] == pytest.approx(watch, rel=1e-6)
        # outside the commands' span the frame's own targets count: within limits
        await rig.send(frame(17))
        assert rig.alarms()[0]["state"] == "cleared"
        await rig.send(frame(18, {0: watch}))  # the vehicle's own error after the plan
        assert rig.alarms()[0]["state"] == "triggered"

    run(database_url, scenario)


def test_after_an_abort_the_frames_own_targets_count(tmp_path: Any) -> None:
    from server.storage.db import sqlite_url

    async def scenario(rig: Rig) -> None:
        targets = [float(np.radians(3 * value_in(TRACKING, C)))] + [0.0] * 5
        await start_pass(rig, [(T0_NS, targets), (T0_NS + 100 * PERIOD_NS, targets)])
        await rig.send(frame(1))
        [alarm] = rig.alarms()
        assert alarm["current_severity"] == "critical"
        await end_pass(rig, "aborted")
        await rig.send(frame(2))  # the arm held where it is: the vehicle's targets
        assert rig.alarms()[0]["state"] == "cleared"

    run(sqlite_url(tmp_path), scenario)
