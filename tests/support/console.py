"""The console's websocket from both sides, as the console tests drive it: the ground's
application fed the way the link feeds it (passes stored, events published, telemetry through
the real link), and a console's messages (control, replays run to a state, telemetry read
back as rows)."""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from fastapi.testclient import TestClient
from sqlalchemy.orm import Session
from starlette.testclient import WebSocketTestSession

from planner.plan import Plan
from server.services.clock import Clock
from server.services.console import ConsoleHub
from server.services.dbworker import Database
from server.services.downlink import GroundDownlink
from server.services.events import CommandStage, Event, Recorded, record
from server.services.link import Connection, GroundLink
from server.storage import repository as repo
from spacecraft.offline import OfflineFlight
from telemetry.uplink import plan_commands
from telemetry.wire import Hello, TelemetryFrame, TelemetryMsg, encode
from tests.server.storage.factories import T0_NS
from tests.support.api import VIEWER


def frames_of(messages: list[dict[str, Any]]) -> dict[int, dict[str, Any]]:
    """Frame seq -> its values, from telemetry messages (columns to rows)."""
    out: dict[int, dict[str, Any]] = {}
    for message in messages:
        columns = message["columns"]
        assert all(len(c) == message["count"] for c in columns.values())
        for i, seq in enumerate(columns["seq"]):
            out[seq] = {name: values[i] for name, values in columns.items()}
    return out


Flight = tuple[Plan, OfflineFlight]


def send(ws: WebSocketTestSession, type_: str, **fields: Any) -> None:
    ws.send_json({"v": 1, "type": type_, **fields})


def open_replay(ws: WebSocketTestSession, pass_id: str, **fields: Any) -> dict[str, Any]:
    send(ws, "replay_open", pass_id=pass_id, **fields)
    reply: dict[str, Any] = ws.receive_json()
    assert reply["type"] == "replay_opened", reply
    return reply


def until_state(
    ws: WebSocketTestSession, done: Callable[[dict[str, Any]], bool]
) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """Replay data up to the first ``replay_state`` for which ``done`` holds (other states,
    e.g. progress reports, are passed over)."""
    data = []
    while True:
        message: dict[str, Any] = ws.receive_json()
        if message.get("topic") == "replay":
            data.append(message)
        elif message["type"] == "replay_state" and done(message):
            return data, message
        else:
            assert message["type"] == "replay_state", message


def until_finished(ws: WebSocketTestSession) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    return until_state(ws, lambda m: bool(m["finished"]))


CONSOLE = "/api/console"


#: A viewer's token, in the header (there is no ?token=: a token in a URL ends up in logs).
AS_VIEWER = VIEWER


def hub(client: TestClient) -> ConsoleHub:
    console: ConsoleHub = client.app.state.console  # type: ignore[attr-defined]
    return console


def link(client: TestClient) -> GroundLink:
    ground_link: GroundLink = client.app.state.link  # type: ignore[attr-defined]
    return ground_link


def downlink(client: TestClient) -> GroundDownlink:
    ground_downlink: GroundDownlink = client.app.state.downlink  # type: ignore[attr-defined]
    return ground_downlink


#: Ground time at which a flown pass's batches were received (batch k: + k ms).
RECEIVED_NS = 1_717_171_717_000_000_000


def add_flown_pass(
    client: TestClient, flight: tuple[Plan, OfflineFlight], name: str = "flown", batch: int = 8
) -> str:
    """Store the flight as a completed pass (plan, commands, frames in batches of ``batch``,
    epoch) as the link would have; its id."""
    plan, flown = flight
    now = time.time_ns()
    with client.app.state.sessions() as session:  # type: ignore[attr-defined]
        plan_id = repo.add_plan(session=session, plan=plan, created_at_ns=now).id
        pass_id = repo.add_pass(
            session=session,
            name=name,
            plan_id=plan_id,
            aos_time_ns=now,
            los_time_ns=now + 10**12,
            relay="TDRS-W",
            created_at_ns=now,
        ).id
        commands = plan_commands(plan, epoch_ns=flown.epoch_ns, first_seq=0)
        repo.add_commands(session=session, pass_id=pass_id, commands=commands, queued_at_ns=now)
        for k, lo in enumerate(range(0, len(flown.frames), batch)):
            repo.ingest_frames(
                session=session,
                pass_id=pass_id,
                frames=flown.frames[lo : lo + batch],
                reception_time_ns=RECEIVED_NS + k * 10**6,
            )
        repo.update_pass_state(
            session=session,
            pass_id=pass_id,
            expected_version=1,
            state="complete",
            updated_at_ns=now,
            epoch_ns=flown.epoch_ns,
        )
        session.commit()
    return pass_id


_numbers = itertools.count(1)


@dataclass(frozen=True, kw_only=True)
class _Emitted(Event):
    """An event of any kind a test names, its detail as given."""

    info: dict[str, Any]

    def detail(self) -> dict[str, Any]:
        return dict(self.info)


def _emitted(kind: str) -> type[_Emitted]:
    return type(f"Emitted_{kind}", (_Emitted,), {"kind": kind})


def emit_events(
    client: TestClient,
    kinds: list[str],
    pass_id: str | None = None,
    detail: dict[str, Any] | None = None,
) -> list[dict[str, Any]]:
    """Write one event of each kind (committed, in order) and publish them as the link does;
    each carries a unique ``detail.n`` (and ``detail``'s items, if given)."""
    details = [{"n": next(_numbers), "seq": 7, "stage": "sent", **(detail or {})} for _ in kinds]

    db: Database = client.app.state.db  # type: ignore[attr-defined]
    clock: Clock = client.app.state.clock  # type: ignore[attr-defined]

    def job(session: Session) -> list[dict[str, Any]]:
        return [
            record(session, _emitted(kind)(actor="tester", pass_id=pass_id, info=detail), now)
            for kind, detail in zip(kinds, details, strict=True)
            for now in [clock.time_ns()]
        ]

    client.portal.call(db.write, job)  # type: ignore[union-attr]
    return details


class FakeSpacecraft:
    """Telemetry through the real :class:`GroundLink` (stored, then published) without a
    spacecraft process: a connection that discards what the ground sends."""

    def __init__(self, client: TestClient, pass_id: str):
        self.client = client
        ground = link(client)

        async def discard(_: Any, *__: Any) -> None:
            return None

        self.conn = Connection(actor="ets7", send_text=discard, close=discard)
        portal = client.portal
        assert portal is not None
        self.portal = portal
        hello = Hello(
            vehicle="ETS-VII", onboard_time_ns=T0_NS, time_scale=1.0, next_telemetry_seq=0
        )
        portal.call(ground.attach, self.conn)
        portal.call(ground.handle, self.conn, encode(hello))
        downlink(client).open_window(pass_id, 0)

    def send(self, frames: list[TelemetryFrame]) -> None:
        message = encode(TelemetryMsg(frames=frames))
        ground = link(self.client)
        self.portal.call(ground.handle, self.conn, message)
        # the link reads on while frames commit: wait until they are stored and published
        self.portal.call(downlink(self.client).settled)


def drain(ws: WebSocketTestSession) -> list[dict[str, Any]]:
    """Every message queued for the console before now: a ping, and what came before its
    pong (the server answers in order, so no timeout is needed)."""
    marker = f"drain-{next(_numbers)}"
    ws.send_json({"v": 1, "type": "ping", "id": marker})
    out: list[dict[str, Any]] = []
    while True:
        message: dict[str, Any] = ws.receive_json()
        if message["type"] == "pong" and message["id"] == marker:
            return out
        out.append(message)


def subscribe(ws: WebSocketTestSession, **fields: Any) -> dict[str, Any]:
    """Subscribe and return the ``subscribed`` reply (the first message after it)."""
    ws.send_json({"v": 1, "type": "subscribe", **fields})
    reply: dict[str, Any] = ws.receive_json()
    assert reply["type"] == "subscribed", reply
    return reply


def welcome(ws: WebSocketTestSession) -> dict[str, Any]:
    message: dict[str, Any] = ws.receive_json()
    assert message["type"] == "welcome", message
    return message


def stage_event(n: int, pass_id: str | None = None) -> Recorded:
    """The ``n``-th command's move from released to sent, at ``n`` ns, as the database
    worker publishes it to the consoles (event id ``n``)."""
    stage = CommandStage(
        actor="ground", pass_id=pass_id, seq=n, from_stage="released", stage="sent", time_ns=n
    )
    return Recorded(stage, n, n)
