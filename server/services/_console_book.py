"""The console hub's streams and what feeds them (:mod:`server.services.console`): the
in-process publisher's events, frames and alarms, numbered here, or across grounds the same
from JetStream, numbered by it (:mod:`server.services._console_jetstream`); and a poll of
this ground's link status. Everything here runs on the event loop and never blocks."""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from dataclasses import asdict, replace
from typing import TYPE_CHECKING, Any

from server.services._console_limits import (
    ENDED_STATES,
    EVENT_TOPICS,
    RETIRED_KEPT,
    ConsoleLimits,
    canonical_pass,
)
from server.services._console_replay import TelemetryRows, telemetry_rows
from server.services._console_streams import LinkReport, Payload, Stream
from server.services.console_messages import ConsoleEvent, console_event
from server.services.event_log import Recorded
from server.services.link import LinkStatus
from telemetry.alarm import AlarmPublic
from telemetry.wire import TelemetryFrame

if TYPE_CHECKING:
    from server.services._console_jetstream import AcrossGrounds

__all__ = ["StreamBook"]

log = logging.getLogger("hikoboshi.ground.console")


class StreamBook:
    """Every stream of one hub, by ``(topic, pass_id)``; each message is offered to the
    stream's subscriptions as it is appended."""

    def __init__(
        self,
        limits: ConsoleLimits,
        link_status: Callable[[], LinkStatus],
        across: AcrossGrounds | None,
    ) -> None:
        self.limits = limits
        self.across = across
        self._link_status = link_status
        self.streams: dict[tuple[str, str | None], Stream] = {}
        #: passes seen ending whose telemetry stream is still held
        self._ended: set[str] = set()
        #: the last seq of each retired telemetry stream, by pass (see :meth:`retire`)
        self._retired: dict[str, int] = {}

    def stream(self, topic: str, pass_id: str | None = None) -> Stream:
        stream = self.streams.get((topic, pass_id))
        if stream is None:
            # across grounds: no message of it came since the hub began following JetStream
            floor = 0 if self.across is None else self.across.position
            stream = Stream(topic, pass_id, self.limits, floor)
            self.streams[(topic, pass_id)] = stream
            if pass_id is not None and pass_id in self._retired:
                # a late frame or a new subscription of an ended pass: the numbering goes on
                # (an earlier seq is no longer held: resync), and it is retired again
                stream.last_seq = stream.floor = self._retired.pop(pass_id)
                self._ended.add(pass_id)
        return stream

    def retire(self) -> None:
        """Let go of the telemetry streams of ended passes nobody subscribes to: each held a
        ring of its pass's last messages for good, some megabytes a pass, so a ground flying
        pass after pass grew without bound. Only the stream's last seq is kept."""
        for pass_id in list(self._ended):
            stream = self.streams.get(("telemetry", pass_id))
            if stream is None:
                self._ended.discard(pass_id)
            elif not stream.subscriptions:
                del self.streams[("telemetry", pass_id)]
                self._ended.discard(pass_id)
                self._retired[pass_id] = stream.last_seq
        while len(self._retired) > RETIRED_KEPT:
            del self._retired[next(iter(self._retired))]

    def push(self, stream: Stream, key: Any, payload: Payload, seq: int | None) -> None:
        message = stream.append(key, payload, seq)
        for sub in list(stream.subscriptions):
            sub.offer(message, live=True)

    def on_event(self, recorded: Recorded) -> None:
        event = console_event(recorded)
        self.deliver_event(event, (event.time_ns, event.kind, event.pass_id))

    def deliver_event(self, event: ConsoleEvent, key: Any, seq: int | None = None) -> None:
        """An event into every topic that carries its kind (numbered by JetStream: ``seq``)."""
        for topic, kinds in EVENT_TOPICS.items():
            if kinds is None or event.kind in kinds:
                self.push(self.stream(topic), key, event, seq)
        ended = event.detail.get("to") in ENDED_STATES
        if event.kind == "pass_state" and event.pass_id is not None and ended:
            self._ended.add(event.pass_id)
            self.retire()

    def on_frames(self, pass_id: str, frames: list[TelemetryFrame], reception_time_ns: int) -> None:
        if not frames:
            return
        batch = telemetry_rows(frames, reception_time_ns)
        rows = batch.rows
        key = (reception_time_ns, rows[0][1], max(r[1] for r in rows), len(rows))
        self.deliver_frames(canonical_pass(pass_id), batch, key)

    def deliver_frames(
        self, pass_id: str | None, batch: TelemetryRows, key: Any, seq: int | None = None
    ) -> None:
        self.push(self.stream("telemetry", pass_id), key, batch, seq)

    def on_alarm(self, alarm: AlarmPublic) -> None:
        self.deliver_alarm(alarm)

    def deliver_alarm(self, alarm: AlarmPublic, seq: int | None = None) -> None:
        self.push(self.stream("alarms"), None, alarm, seq)

    def deliver_link(self, report: LinkReport, seq: int | None = None) -> None:
        self.push(self.stream("link"), None, report, seq)

    def with_this_ground(self, report: LinkReport) -> LinkReport:
        """Another ground's link report (across grounds, the holder's) with this ground's
        own ``ground``: a console shows whether the ground it is on commands the vehicle,
        and whether that ground's database answers."""
        ground = self._link_status().ground
        return report._replace(status=replace(report.status, ground=ground))

    def push_link_status(self, status: LinkStatus) -> None:
        """This ground's link status: to its consoles, or across grounds to JetStream (the
        holder's only: the standby's link carries no vehicle)."""
        report = LinkReport(time.time_ns(), status)
        if self.across is None:
            self.deliver_link(report)
        else:
            self.across.publish_link(report)

    async def poll_link(self) -> None:
        previous: dict[str, Any] | None = None
        pushed = -float("inf")
        while True:
            try:
                status = self._link_status()
                # The onboard clock always moves: a change is anything else.
                compare = {**asdict(status), "onboard_time_ns": None}
                now = time.monotonic()
                if compare != previous or now - pushed >= self.limits.link_heartbeat_s:
                    self.push_link_status(status)
                    previous, pushed = compare, now
            except Exception:
                log.exception("link status poll failed")
            await asyncio.sleep(self.limits.link_poll_s)
