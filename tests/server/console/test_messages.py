"""The server -> console messages are the models of ``console_messages``: their text is the
protocol's (fields in order, compact, nothing left out or added), and every message a
console receives fits the JSON Schema the web console's types are generated from."""

from __future__ import annotations

import json
from dataclasses import asdict
from typing import Any

import jsonschema
import pytest
from fastapi.testclient import TestClient
from pydantic.json_schema import models_json_schema
from starlette.testclient import WebSocketTestSession

from server.services._console_protocol import RealTimeSpec
from server.services.console_messages import (
    SERVER_MESSAGES,
    ConsoleEvent,
    ErrorMsg,
    EventMsg,
    FrameColumns,
    LagMsg,
    LinkMsg,
    PongMsg,
    ReplayCommand,
    ReplayCommandsMsg,
    ReplayOpenedMsg,
    ReplayStateMsg,
    SubscribedMsg,
    TelemetryMsg,
    UnsubscribedMsg,
    WelcomeLimits,
    WelcomeMsg,
)
from server.services.link import LinkStatus, ScheduleStatus
from tests.server.storage.factories import make_frames
from tests.support.api import add_pass
from tests.support.console import (
    AS_VIEWER,
    CONSOLE,
    FakeSpacecraft,
    Flight,
    add_flown_pass,
    drain,
    emit_events,
    open_replay,
    send,
    until_finished,
    welcome,
)

pytestmark = pytest.mark.realtime  # flies a vehicle or serves a live link in wall time


def test_messages_are_the_text_the_protocol_has_always_sent() -> None:
    # pass_id and an event's id are left out when None; ints stay ints; fields in order
    assert (
        SubscribedMsg(topic="commands", epoch="e1", seq=3).encode()
        == '{"v":1,"type":"subscribed","topic":"commands","epoch":"e1","seq":3}'
    )
    assert (
        UnsubscribedMsg(topic="telemetry", pass_id="p", seq=4, reason="requested").encode()
        == '{"v":1,"type":"unsubscribed","topic":"telemetry","pass_id":"p","seq":4,'
        '"reason":"requested"}'
    )
    event = {"kind": "k", "actor": "a", "detail": {"x": 1.5}, "pass_id": None, "time_ns": 9}
    assert (
        EventMsg(topic="events", seq=1, event=ConsoleEvent.model_validate(event)).encode()
        == '{"v":1,"topic":"events","type":"event","seq":1,"event":{"kind":"k","actor":"a",'
        '"detail":{"x":1.5},"pass_id":null,"time_ns":9}}'
    )
    assert ConsoleEvent.model_validate({**event, "id": 7}).model_dump()["id"] == 7
    assert PongMsg(id=None, time_ns=5).encode() == '{"v":1,"type":"pong","id":null,"time_ns":5}'
    assert (
        LagMsg(behind_s=2.5, queued=40, resync_s=5.0, time_ns=9).encode()
        == '{"v":1,"type":"lag","behind_s":2.5,"queued":40,"resync_s":5.0,"time_ns":9}'
    )
    assert (
        ErrorMsg(reason="r", ref_type=None).encode()
        == '{"v":1,"type":"error","reason":"r","ref_type":null}'
    )
    limits = WelcomeLimits(
        queue_bytes=1,
        ring_size=2,
        max_replay=3,
        max_subscriptions=4,
        max_message_bytes=5,
        link_heartbeat_s=6,
        behind_report_s=0.5,
        behind_resync_s=5,
        behind_drop_s=30.0,
        ack_window_s=1.0,
        max_replays_per_console=7,
        max_replay_factor=8.5,
        max_replay_batch_frames=9,
    )
    text = WelcomeMsg(epoch="e", actor="vera", role="viewer", topics=["a"], limits=limits).encode()
    assert text == (
        '{"v":1,"type":"welcome","epoch":"e","actor":"vera","role":"viewer","topics":["a"],'
        '"limits":{"queue_bytes":1,"ring_size":2,"max_replay":3,"max_subscriptions":4,'
        '"max_message_bytes":5,"link_heartbeat_s":6,"behind_report_s":0.5,'
        '"behind_resync_s":5,"behind_drop_s":30.0,"ack_window_s":1.0,"max_replays_per_console":7,'
        '"max_replay_factor":8.5,"max_replay_batch_frames":9}}'
    )
    columns = FrameColumns({"seq": [1], "generation_time_ns": [2], "j1": [0.5]})
    assert (
        TelemetryMsg(pass_id="p", seq=1, count=1, columns=columns).encode()
        == '{"v":1,"topic":"telemetry","type":"telemetry","pass_id":"p","seq":1,"count":1,'
        '"columns":{"seq":[1],"generation_time_ns":[2],"j1":[0.5]}}'
    )
    state = dict(
        replay_id="r",
        pass_id="p",
        seq=0,
        reason="open",
        playing=False,
        finished=False,
        speed=RealTimeSpec(mode="real_time", factor=2.0),
        position=0,
        frames=10,
        next_generation_time_ns=None,
        playhead_ns=1,
        playhead_t_s=0.5,
    )
    opened = ReplayOpenedMsg(
        **state,
        name="n",
        epoch_ns=0,
        commands=2,
        first_generation_time_ns=1,
        last_generation_time_ns=2,
        plan_duration_s=3.0,
        columns=["seq"],
    )
    assert opened.encode() == (
        '{"v":1,"type":"replay_opened","replay_id":"r","pass_id":"p","seq":0,"reason":"open",'
        '"playing":false,"finished":false,"speed":{"mode":"real_time","factor":2.0},'
        '"position":0,"frames":10,"next_generation_time_ns":null,"playhead_ns":1,'
        '"playhead_t_s":0.5,"name":"n","epoch_ns":0,"commands":2,"first_generation_time_ns":1,'
        '"last_generation_time_ns":2,"plan_duration_s":3.0,"columns":["seq"]}'
    )
    assert ReplayStateMsg(**state).encode().startswith('{"v":1,"type":"replay_state","replay_id"')


def _schema() -> dict[str, Any]:
    """Any server message, by the JSON Schema ``python -m server.webtypes`` reads."""
    _, top = models_json_schema(
        [(model, "validation") for model in SERVER_MESSAGES], ref_template="#/$defs/{model}"
    )
    refs = [{"$ref": f"#/$defs/{model.__name__}"} for model in SERVER_MESSAGES]
    return {"$defs": top["$defs"], "anyOf": refs}


def _until_pong(ws: WebSocketTestSession, marker: str) -> list[dict[str, Any]]:
    ws.send_json({"v": 1, "type": "ping", "id": marker})
    out: list[dict[str, Any]] = []
    while True:
        out.append(ws.receive_json())
        if out[-1]["type"] == "pong" and out[-1]["id"] == marker:
            return out


def test_every_message_a_console_receives_fits_the_schema(
    client: TestClient, flight: Flight
) -> None:
    validator = jsonschema.Draft202012Validator(_schema())
    live_pass = add_pass(client, "live")
    flown_pass = add_flown_pass(client, flight)
    spacecraft = FakeSpacecraft(client, live_pass)
    received: list[dict[str, Any]] = []
    with client.websocket_connect(CONSOLE, headers=AS_VIEWER) as ws:
        received.append(welcome(ws))
        for topic in ("commands", "passes", "events", "link"):
            send(ws, "subscribe", topic=topic)
        send(ws, "subscribe", topic="telemetry", pass_id=live_pass)
        received += drain(ws)
        emit_events(client, ["command_stage", "pass_state", "link_hello"], live_pass)
        spacecraft.send(make_frames(range(5)))
        received += drain(ws)
        # a filtered telemetry stream, a resync, an unsubscribe, an error
        send(ws, "subscribe", topic="telemetry", pass_id=live_pass, fields=["j2", "acs_mode"])
        spacecraft.send(make_frames(range(5, 10)))
        send(ws, "subscribe", topic="events", since_seq=0, epoch="another")
        send(ws, "unsubscribe", topic="passes")
        send(ws, "subscribe", topic="nothing")
        received += _until_pong(ws, "a")
        # a replay, its commands, and its close
        # no live message amid the replay's: an event of the frames above is published
        # after its commit, which on a loaded machine came after the pong below
        for topic in ("link", "events", "commands"):
            send(ws, "unsubscribe", topic=topic)
        send(ws, "unsubscribe", topic="telemetry", pass_id=live_pass)
        received += _until_pong(ws, "b")
        received.append(open_replay(ws, flown_pass, speed={"mode": "as_fast_as_possible"}))
        data, state = until_finished(ws)
        received += [*data, state]
        send(ws, "replay_close", replay_id=state["replay_id"])
        received += _until_pong(ws, "c")
    for message in received:
        errors = sorted(validator.iter_errors(message), key=str)
        assert not errors, (message, [e.message for e in errors[:3]])
    seen = {(m.get("topic"), m["type"]) for m in received}
    assert {t for _, t in seen} >= {
        "welcome",
        "subscribed",
        "resync",
        "unsubscribed",
        "pong",
        "error",
        "telemetry",
        "link",
        "event",
        "replay_opened",
        "replay_state",
        "replay_closed",
        "commands",
    }, seen
    assert ("replay", "telemetry") in seen and ("telemetry", "telemetry") in seen
    # The schema is not a rubber stamp: what a message must not be, it refuses.
    bad = [
        {"v": 1, "type": "pong", "id": 1, "time_ns": "soon"},
        {"v": 1, "topic": "telemetry", "type": "telemetry", "pass_id": "p", "seq": 1,
         "count": 1, "columns": {"seq": [1], "generation_time_ns": [2],
                                 "reception_time_ns": [3], "acs_mode": [4]}},
        {"v": 1, "type": "subscribed", "topic": "x", "epoch": "e", "seq": 1, "extra": 1},
    ]  # fmt: skip
    for message in bad:
        assert not validator.is_valid(message), message


def test_the_text_is_the_models_document_and_a_link_status_is_its_dataclass() -> None:
    schedule = ScheduleStatus(
        queued=3, capacity=10, free=7, first_tag_ns=5, last_tag_ns=None, lead_s=1.5, as_of_ns=2
    )
    status = LinkStatus(
        connected=True,
        actor="ets7",
        vehicle="ETS-VII",
        time_scale=1.0,
        onboard_time_ns=4,
        round_trip_s=None,
        frames_received=9,
        duplicates=0,
        frames_outside_pass=0,
        highest_seq=8,
        frames_behind=None,
        open_gaps=[(1, 2)],
        frames_missing=2,
        retransmit_requests=1,
        errors_replied=0,
        errors_received=0,
        schedule=schedule,
        uplink={"pass_id": "p", "sent": 3},
    )
    link = LinkMsg(seq=2, ground_time_ns=7, status=status)
    assert json.loads(link.encode()) == {
        "v": 1,
        "topic": "link",
        "type": "link",
        "seq": 2,
        "ground_time_ns": 7,
        "status": json.loads(json.dumps(asdict(status))),
    }
    command = ReplayCommand(
        seq=1,
        kind="joints",
        execute_time_ns=5,
        stage="executed",
        reject_reason=None,
        stage_times_ns={"queued": 1, "sent": None},
        payload={"joints_rad": [0.1, 0.2]},
    )
    event = ConsoleEvent(kind="k", actor="a", detail={}, pass_id="p", time_ns=1, id=None)
    for message in (
        link,
        ReplayCommandsMsg(replay_id="r", pass_id="p", seq=3, commands=[command]),
        EventMsg(topic="commands", seq=1, event=event),
        SubscribedMsg(topic="telemetry", pass_id="p", epoch="e", seq=1),
    ):
        assert message.encode() == json.dumps(message.model_dump(), separators=(",", ":"))
    assert '"id"' not in EventMsg(topic="commands", seq=1, event=event).encode()
