"""A ground's live path in simulated time with one stored pass, fed telemetry frames straight
into its downlink (no relay): what the alarm tests drive.

Frames are ETS-VII's, nominal (pose A, the attitude on its target, nothing moving, an empty
schedule) unless a test sets a joint's measured angle off its target; the bands come from
the description's own limits, so the tests hold whatever thresholds it gives.
"""

from __future__ import annotations

import asyncio
from collections.abc import Iterator
from typing import Any

import numpy as np

from planner.description import default_robot
from planner.limits import Bands, Severity
from server.app import LivePath, build_live_path
from server.services.clock import ManualClock
from server.settings import Settings
from server.storage import alarms as alarm_repo
from server.storage import repository as repo
from server.storage.db import make_engine, session_factory, upgrade
from telemetry.wire import AcsModeName, BufferState, TelemetryFrame, TelemetryMsg
from tests.server.link.harness import add_plan_and_pass
from tests.server.link.simulated import EPOCH_NS, Ground, SimulatedSpacecraft
from tests.server.storage.factories import make_plan

#: Frame 0's onboard time: the simulated vehicle's clock when the rig connects it.
T0_NS = EPOCH_NS
PERIOD_NS = 100_000_000
TRACKING = "joint_tracking_error_deg"


def bands(quantity: str) -> Bands:
    return default_robot().limits.bands[quantity]


def value_in(quantity: str, severity: Severity) -> float:
    """A value inside ``severity``'s band of a "high" quantity (between its threshold and
    the next one up, or 20 % past it for the worst band)."""
    b = bands(quantity)
    levels = [t for _, t in b.thresholds]
    k = [s for s, _ in b.thresholds].index(severity)
    upper = levels[k + 1] if k + 1 < len(levels) else levels[k] * 1.4
    return levels[k] + 0.5 * (upper - levels[k])


def below(quantity: str) -> float:
    """A value of a "high" quantity within limits (half its lowest threshold)."""
    return 0.5 * bands(quantity).thresholds[0][1]


def frame(seq: int, error_deg: dict[int, float] | None = None) -> TelemetryFrame:
    """Frame ``seq`` (10 Hz from T0): nominal, joint ``k`` (0-based) measured
    ``error_deg[k]`` below its target."""
    targets = np.zeros(6)
    joints = targets.copy()
    for k, e in (error_deg or {}).items():
        joints[k] = targets[k] - np.radians(e)
    return TelemetryFrame(
        seq=seq,
        generation_time_ns=T0_NS + seq * PERIOD_NS,
        joints_rad=joints.tolist(),
        joint_targets_rad=targets.tolist(),
        quat_orbit_from_base_xyzw=[0.0, 0.0, 0.0, 1.0],
        omega_base_in_base_radps=[0.0, 0.0, 0.0],
        wheel_speeds_radps=[0.0, 0.0, 0.0],
        wheel_momentum_nms=[0.0, 0.0, 0.0],
        acs_mode=AcsModeName.FEEDBACK,
        acs_target_quat_xyzw=[0.0, 0.0, 0.0, 1.0],
        acs_feedforward=False,
        buffer=BufferState(queued=0, capacity=1024),
    )


class Rig:
    """The live path (``live``) on ``url``, a ManualClock, a simulated vehicle connected
    (its onboard clock at :data:`T0_NS` when :meth:`connect` is awaited, no delay), and a
    stored pass (``pass_id``: a new one) whose telemetry window is open from onboard 0."""

    def __init__(self, url: str, *, pass_id: str | None = None, **settings: Any) -> None:
        self.engine = make_engine(url)
        upgrade(self.engine)
        self.sessions = session_factory(self.engine)
        self.clock = ManualClock()
        self.live: LivePath = build_live_path(
            sessions=self.sessions, settings=Settings(**settings), clock=self.clock
        )
        if pass_id is None:
            pass_id = self.new_pass()
        else:
            self.live.downlink.open_window(pass_id, 0)
        self.pass_id = pass_id
        self.published: list[dict[str, Any]] = []
        #: every alarm published, as its JSON
        self.live.publisher.subscribe_alarms(
            lambda alarm: self.published.append(alarm.model_dump(mode="json"))
        )
        self.vehicle = SimulatedSpacecraft(self.clock, delay_s=0.0)

    async def connect(self) -> None:
        live = self.live
        await self.vehicle.connect(
            Ground(live.link, live.runner, self.sessions, live.db, live.downlink)
        )
        await live.alarms.load_vehicle_alarms()

    def new_pass(self) -> str:
        pass_id = add_plan_and_pass(
            self.sessions, make_plan(9), "alarms", now_ns=self.clock.time_ns(), window_s=3600.0
        )
        self.live.downlink.open_window(pass_id, 0)
        return pass_id

    async def send(self, *frames: TelemetryFrame) -> None:
        """One telemetry message of these frames, stored, checked and its alarms written."""
        await self.live.downlink.on_telemetry(TelemetryMsg(frames=list(frames)))
        await self.settled()

    async def settled(self) -> None:
        await self.live.downlink.settled()
        await self.live.alarms.settled()
        await self.live.db.drain()
        await self.clock.settle()

    def alarms(self, **kw: Any) -> list[dict[str, Any]]:
        with self.sessions() as session:
            page = alarm_repo.list_alarms(session=session, **kw)
            return [alarm_repo.alarm_document(r) for r in page.items]

    def events(self, *kinds: str) -> list[Any]:
        with self.sessions() as session:
            return list(repo.list_events(session=session, kinds=list(kinds), limit=1000).items)

    async def close(self) -> None:
        await self.live.alarms.close()
        await self.live.db.drain()
        self.live.db.close()
        self.engine.dispose()


def severities(alarm: dict[str, Any]) -> list[str | None]:
    return [entry["severity"] for entry in alarm["timeline"]]


def seqs(n: int, start: int = 0) -> Iterator[int]:
    return iter(range(start, start + n))


def run(url: str, scenario: Any, **settings: Any) -> Any:
    """``scenario(rig)`` on a connected :class:`Rig` of ``url``, closed after."""

    async def main() -> Any:
        rig = Rig(url, **settings)
        await rig.connect()
        try:
            return await scenario(rig)
        finally:
            await rig.close()

    return asyncio.run(main())


async def start_pass(rig: Rig, joint_targets: list[tuple[int, list[float]]]) -> None:
    """The pass goes running (as the runner's start writes it) with these joint commands
    (tag, targets rad): the events the monitor follows, the rows it reads."""
    from server.services.pass_states import transition
    from server.storage import repository as repo
    from telemetry.wire import JointCommandMsg

    commands = [
        JointCommandMsg(seq=k, execute_time_ns=tag, joints_rad=targets)
        for k, (tag, targets) in enumerate(joint_targets)
    ]
    clock, pass_id = rig.clock, rig.pass_id

    def job(session: Any) -> list[dict[str, Any]]:
        repo.add_commands(
            session=session, pass_id=pass_id, commands=commands, queued_at_ns=clock.time_ns()
        )
        now = clock.time_ns()
        return [
            transition(session, clock, pass_id, "aos", "op", "start", now),
            transition(session, clock, pass_id, "running", "op", "start", now, T0_NS),
        ]

    await rig.live.db.write(job)
    await rig.settled()


async def end_pass(rig: Rig, state: str) -> None:
    """The pass goes ``state`` with its ``pass_state`` event, written as a transition is
    (whichever module owns the rule that gets it there)."""
    from server.services.events import PassState, record
    from server.storage import repository as repo

    clock, pass_id = rig.clock, rig.pass_id

    def job(session: Any) -> list[dict[str, Any]]:
        old = repo.get_pass(session=session, pass_id=pass_id, refresh=True)
        was = old.state
        new = repo.update_pass_state(
            session=session,
            pass_id=pass_id,
            expected_version=old.version,
            state=state,
            updated_at_ns=clock.time_ns(),
            reason="ended",
        )
        event = PassState(
            actor="op", pass_id=pass_id, from_state=was, to=state, reason="ended",
            version=new.version,
        )  # fmt: skip
        return [record(session, event, clock.time_ns())]

    await rig.live.db.write(job)
    await rig.settled()
