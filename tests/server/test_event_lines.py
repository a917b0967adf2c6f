"""The operator's log lines of committed events (server.services.event_lines): one line per
pass state change, safing, safe exit, alarm raised / cleared / acknowledged and refusal,
each naming what an operator must hear, at a level that matches, in text and JSON alike;
the other kinds write none."""

from __future__ import annotations

import json
import logging

import pytest

from planner.limits import Severity
from server.logs import JsonFormatter, TextFormatter
from server.services.event_lines import ALARM_LEVELS, LOGGED_KINDS, log_event
from server.services.events import (
    AlarmAcknowledged,
    AlarmCleared,
    AlarmRaised,
    CommandStage,
    Event,
    LinkHello,
    PassControlRefused,
    PassStartRefused,
    PassState,
    Recorded,
    VehicleSafed,
    VehicleSafeExited,
    VehicleSafeExitRequested,
    VehicleSafeExitUnverified,
)
from server.services.publisher import Publisher

P = "5a655b22-17b5-4e69-a743-48c5b156273d"
ALARM = {"alarm_id": "a1", "quantity": "joint_tracking_error_deg", "channel": "joint3"}

#: each kind's event, the level of its line and what the line must say
CASES: list[tuple[Event, int, list[str]]] = [
    (
        PassState(actor="otto", pass_id=P, from_state="running", to="aborted", reason="by hand",
                  version=3),
        logging.WARNING,
        ["running -> aborted: by hand (otto)"],
    ),
    (
        PassState(actor="ground", pass_id=P, from_state="los", to="complete", reason="nominal",
                  version=4),
        logging.INFO,
        ["los -> complete: nominal"],
    ),
    (
        VehicleSafed(actor="ets7", pass_id=P, since_time_ns=5, cancelled=12,
                     trigger={**ALARM, "value": 2.5, "limit": 2.0}),
        logging.ERROR,
        ["vehicle SAFE", "joint_tracking_error_deg joint3 2.5 against 2", "12 commands dropped"],
    ),
    (
        AlarmRaised(actor="ground", pass_id=P, **ALARM, source="frame", severity="critical",
                    value=2.5, limit=2.0, frame_seq=7, generation_time_ns=9),
        logging.ERROR,
        ["alarm CRITICAL: joint_tracking_error_deg joint3 = 2.5 (limit 2)"],
    ),
    (
        AlarmRaised(actor="ground", pass_id=P, **ALARM, source="frame", severity="watch",
                    value=0.5, limit=0.4, frame_seq=7, generation_time_ns=9, reopened=True),
        logging.INFO,
        ["alarm WATCH again"],
    ),
    (
        AlarmCleared(actor="ground", pass_id=P, **ALARM, severity="warning", value=0.1,
                     generation_time_ns=10),
        logging.INFO,
        ["alarm cleared: WARNING joint_tracking_error_deg joint3 = 0.1"],
    ),
    (
        AlarmAcknowledged(actor="otto", pass_id=P, **ALARM, severity="critical", state="active",
                          comment="seen"),
        logging.INFO,
        ["alarm acknowledged: CRITICAL joint_tracking_error_deg joint3: seen (otto)"],
    ),
    (
        PassStartRefused(actor="otto", pass_id=P, reason="robot_mismatch", message="not ETS-VII",
                         plan_id="p", plan_robot=None, plan_robot_hash=None, plan_n_joints=6,
                         vehicle_robot=None, vehicle_robot_hash=None, vehicle_n_joints=7),
        logging.WARNING,
        ["start refused (robot_mismatch): not ETS-VII"],
    ),
    (
        PassControlRefused(actor="otto", pass_id=P, action="START", confirm="START nope"),
        logging.WARNING,
        ["START refused: the confirmation 'START nope' does not match"],
    ),
    (
        VehicleSafeExitRequested(actor="otto", request_id=4, vehicle="ETS-VII"),
        logging.INFO,
        ["safe exit 4 sent (otto)"],
    ),
    (
        VehicleSafeExited(actor="ets7", request_id=4, since_time_ns=1, onboard_time_ns=2),
        logging.WARNING,
        ["vehicle left SAFE (safe exit 4)"],
    ),
    (
        VehicleSafeExitUnverified(actor="ground", request_id=4, transmissions=5),
        logging.WARNING,
        ["safe exit 4 not confirmed after 5 copies"],
    ),
]  # fmt: skip


def test_every_severity_has_its_level_watch_the_least() -> None:
    assert list(ALARM_LEVELS) == [s.value for s in Severity]
    assert ALARM_LEVELS["watch"] < ALARM_LEVELS["warning"] < ALARM_LEVELS["severe"]
    assert ALARM_LEVELS["severe"] == ALARM_LEVELS["critical"] == logging.ERROR


def test_each_operator_event_is_one_line_saying_what_happened(
    caplog: pytest.LogCaptureFixture,
) -> None:
    assert {event.kind for event, _, _ in CASES} == LOGGED_KINDS
    publisher = Publisher()
    publisher.subscribe(log_event)
    quiet = [
        CommandStage(actor="ets7", pass_id=P, seq=1, from_stage="received", stage="executed",
                     time_ns=5),
        LinkHello(actor="ets7", hello={"vehicle": "ETS-VII", "time_scale": 20.0}),
    ]  # fmt: skip
    with caplog.at_level(logging.INFO, logger="hikoboshi.ground.events"):
        for i, event in enumerate([e for e, _, _ in CASES] + quiet):
            publisher.publish([Recorded(event, 1_000 + i, i)])
    records = [r for r in caplog.records if r.name == "hikoboshi.ground.events"]
    assert len(records) == len(CASES)  # the command stage and the hello write none
    text, as_json = TextFormatter(), JsonFormatter()
    for record, (event, level, said) in zip(records, CASES, strict=True):
        line = record.getMessage()
        assert record.levelno == level, (event.kind, line)
        for part in said:
            assert part in line, (event.kind, line)
        shown = text.format(record)  # the pass once, by the formatter, not in the message
        assert (f"[pass {P}]" in shown) == (event.pass_id is not None) and P not in line
        assert "\n" not in shown
        doc = json.loads(as_json.format(record))
        assert doc["event"] == event.kind and doc["message"] == line
        assert doc.get("pass_id") == event.pass_id
