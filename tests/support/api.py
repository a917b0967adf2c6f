"""The ground's REST API as the tests call it: the tokens and their headers, one cheap real
plan's request, a pass stored directly, the application's own sessions, and a middleware
that gives the test client several addresses."""

from __future__ import annotations

import time
from typing import Any

from fastapi.testclient import TestClient
from sqlalchemy.orm import Session, sessionmaker
from starlette.types import ASGIApp, Receive, Scope, Send

from planner.description import RobotDescription
from planner.plan import plan_for_robot
from server.settings import ApiToken, Role
from server.storage import repository as repo
from telemetry.layout import FrameLayout
from tests.server.storage.factories import make_frames, make_plan, store_pass

#: A viewer's, an operator's and a spacecraft's token, and the headers of the first two.
TOKENS = {
    "v-token": ApiToken(name="vera", role=Role.VIEWER),
    "o-token": ApiToken(name="otto", role=Role.OPERATOR),
    "s-token": ApiToken(name="ets7", role=Role.SPACECRAFT),
}
VIEWER = {"Authorization": "Bearer v-token"}
OPERATOR = {"Authorization": "Bearer o-token"}


#: The cheapest real plan: PTP A -> B with a quarter-second settle (about 0.6 s to plan).
CHEAP_PTP: dict[str, Any] = {"experiment": "ptp", "parameters": {"settle_s": 0.25}}


def sessions(client: TestClient) -> sessionmaker[Session]:
    """The application's own session factory: to store and inspect rows directly."""
    factory: sessionmaker[Session] = client.app.state.sessions  # type: ignore[attr-defined]
    return factory


def add_pass(client: TestClient, name: str = "pass-1", n_joints: int = 6) -> str:
    """A scheduled pass of a small plan of ``n_joints`` joints (stored directly), from now for
    1000 s; its id."""
    now = time.time_ns()
    with sessions(client)() as session:
        plan = repo.add_plan(session=session, plan=make_plan(n_joints=n_joints), created_at_ns=now)
        record = repo.add_pass(
            session=session,
            name=name,
            plan_id=plan.id,
            aos_time_ns=now,
            los_time_ns=now + 10**12,
            relay="TDRS-W",
            created_at_ns=now,
        )
        session.commit()
        return str(record.id)


def recording_of_a_flown_pass(client: TestClient, robot: RobotDescription, n_frames: int) -> bytes:
    """The ground's recording (``recording.mcap``) of a pass of a small plan of ``robot``,
    flown: ``n_frames`` frames stored, its epoch the first's time."""
    n_joints = robot.model.n_joints
    frames = make_frames(range(n_frames), layout=FrameLayout(n_joints, 3))
    with sessions(client)() as session:
        record = store_pass(
            session,
            plan_for_robot(make_plan(n_joints=n_joints), robot),
            name=f"{robot.name}-flown",
            relay="TDRS-W",
            frames=frames,
            reception_time_ns=0,
        )
        record.epoch_ns = int(frames[0].generation_time_ns)
        session.commit()
        pass_id = record.id
    response = client.get(f"/api/passes/{pass_id}/recording.mcap", headers=VIEWER)
    assert response.status_code == 200, response.text
    return response.content


class ClientAddress:
    """Puts the ``x-test-client`` header's address (else ``default``) in the scope as the
    client's: the test client has one address, the edge counts by address."""

    def __init__(self, app: ASGIApp, default: str) -> None:
        self.app = app
        self.default = default

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] in ("http", "websocket"):
            headers = dict(scope["headers"])
            address = headers.get(b"x-test-client", self.default.encode()).decode()
            scope = {**scope, "client": (address, 5555)}
        await self.app(scope, receive, send)
