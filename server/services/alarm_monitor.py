"""One pass's limit checking on the ground (docs/alarms.md): its :class:`PassMonitor`.

A monitor holds the pass's :class:`telemetry.limits.FrameEvaluator` (its robot's
description and ``[limits]``; the commanded joint targets interpolated from the pass's
stored joint commands while it runs, the frame's own targets once it no longer does) and
its :class:`~server.services.alarm_book.AlarmBook`. :meth:`PassMonitor.load` reads them
from storage (a database read, then the evaluator built in a thread); frames that arrive
meanwhile wait in it. :class:`~server.services.alarms.AlarmService` keeps one per pass and
feeds them.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from sqlalchemy.orm import Session

from planner.limits import QUANTITIES, Limits
from planner.plan import Plan
from server.services.alarm_book import AlarmBook, Observation, QuantityInfo
from server.services.dbworker import Database
from server.services.robots import description_for_plan
from server.storage import alarms as alarm_repo
from server.storage import repository as repo
from telemetry.alarm import AlarmPublic
from telemetry.limits import (
    CommandedFn,
    FrameEvaluator,
    Reading,
    for_description,
    interpolated_commands,
)
from telemetry.wire import TelemetryFrame

__all__ = ["PassMonitor", "observation"]

log = logging.getLogger("hikoboshi.ground.alarms")


def _info(limits: Limits) -> Callable[[str], QuantityInfo | None]:
    """A book's quantities: the catalogue's label, unit and direction, the limits' bands."""

    def info(quantity: str) -> QuantityInfo | None:
        spec, bands = QUANTITIES.get(quantity), limits.bands.get(quantity)
        if spec is None or bands is None:
            return None
        return QuantityInfo(spec.label, spec.unit, spec.direction, bands.threshold)

    return info


def observation(r: Reading) -> Observation:
    """A limit checker's reading as the alarm book observes it."""
    return Observation(
        r.quantity, r.channel, r.value, r.severity, r.frame_seq, r.generation_time_ns
    )


@dataclass
class PassMonitor:
    """One pass's limit checking (see the module docstring)."""

    pass_id: str
    book: AlarmBook | None = None
    evaluator: FrameEvaluator | None = None
    limits: Limits | None = None
    commanded: CommandedFn | None = None
    #: the pass's state as the events last said (None: none seen yet)
    state: str | None = None
    loading: asyncio.Task[None] | None = None
    pending: list[TelemetryFrame] = field(default_factory=list)
    last_seq: int = -1
    #: ground ns: the newest frame's reception, else when the pass started running
    last_frame_ns: int | None = None
    #: the evaluator could not be built (its robot unknown here): frames are not checked
    disabled: bool = False

    @property
    def running(self) -> bool:
        """Flying the plan: its commands are the commanded targets."""
        return self.state in ("aos", "running", "los")

    @property
    def watched(self) -> bool:
        """The link's health is watched for it: from its start to its LOS (its telemetry
        window closes there, and no frame of it is expected after)."""
        return self.state == "running"

    def commanded_at(self, times_ns: NDArray[np.int64]) -> NDArray[np.float64] | None:
        if self.commanded is None or not self.running:
            return None
        return self.commanded(times_ns)

    async def load(self, db: Database, robot_files: Sequence[Path]) -> bool:
        """Read the pass's plan, joint commands and listed limit alarms, and build its
        evaluator (``robot_files``: the robot descriptions the server was given): True once
        loaded; False when its frames cannot be checked (then it is ``disabled``)."""
        pass_id = self.pass_id

        def job(session: Session) -> _Loaded:
            record = repo.get_pass(session=session, pass_id=pass_id)
            document = repo.get_plan(session=session, plan_id=record.plan_id).document
            # by tag (the listing's order): the interpolation needs them increasing
            joints = [
                c for c in repo.list_commands(session=session, pass_id=record.id)
                if c.kind == "joints"
            ]  # fmt: skip
            listed = alarm_repo.listed_alarms(session=session, pass_id=record.id)
            return _Loaded(
                record.state,
                document,
                [c.execute_time_ns for c in joints],
                [list(c.payload["joints_rad"]) for c in joints],
                [alarm_repo.stored_alarm(r) for r in listed if r.source == "limit"],
            )

        try:
            loaded = await db.run(job)

            def build() -> tuple[FrameEvaluator, Limits, CommandedFn | None]:
                plan = Plan.from_json(loaded.plan_document)
                description = description_for_plan(plan, robot_files)
                commanded = None
                if loaded.tags_ns:
                    commanded = interpolated_commands(
                        np.asarray(loaded.tags_ns, dtype=np.int64),
                        np.asarray(loaded.targets_rad, dtype=np.float64).reshape(
                            len(loaded.tags_ns), -1
                        ),
                    )
                evaluator = for_description(description, commanded=self.commanded_at)
                return evaluator, description.limits, commanded

            evaluator, limits, commanded = await asyncio.to_thread(build)
        except asyncio.CancelledError:
            raise
        except Exception as exc:
            log.warning("pass %s: its frames are not checked against limits: %s", pass_id, exc)
            self.disabled = True
            self.pending = []
            return False
        if self.state is None:
            self.state = loaded.state
        self.limits, self.commanded = limits, commanded
        self.book = AlarmBook(pass_id, _info(limits), persistence=limits.persistence)
        self.book.restore(loaded.alarms)
        self.evaluator = evaluator
        return True


@dataclass(frozen=True)
class _Loaded:
    state: str
    plan_document: str
    tags_ns: list[int]
    targets_rad: list[list[float]]
    alarms: list[AlarmPublic]
