"""Consoles across grounds (docs/console.md "Across grounds"): the console hub's side of
:mod:`server.services.jetstream`.

:class:`AcrossGrounds` publishes what this ground's :class:`~server.services.dbworker.Publisher`
hands it once committed (events, archived frames, alarms) and, from the lease's holder only,
this ground's link status; and it feeds the hub's streams (:class:`StreamBook`) from
JetStream, every ground's messages alike, each numbered by its JetStream sequence. A resume
that the hub's ring does not cover reads the topic's subjects back from JetStream, from
``since_seq``. Each message is the console's own document, JSON: an event or an alarm as
the console sends it, a telemetry batch as ``{"pass_id", "columns", "rows"}``, a link
report as ``{"ground_time_ns", "status"}``.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable
from dataclasses import asdict
from typing import TYPE_CHECKING, Any

from pydantic import TypeAdapter

from server.services._console_limits import canonical_pass, event_class
from server.services._console_replay import TelemetryRows, telemetry_rows
from server.services._console_streams import LinkReport, Message, Payload, Stream, render
from server.services.console_messages import ConsoleEvent, console_event
from server.services.dbworker import Publisher
from server.services.event_log import Recorded
from server.services.jetstream import LiveBus
from server.services.link import LinkStatus
from telemetry.alarm import AlarmPublic
from telemetry.wire import TelemetryFrame

if TYPE_CHECKING:
    from server.services._console_book import StreamBook

__all__ = ["AcrossGrounds"]

log = logging.getLogger("hikoboshi.ground.console")

_LINK_STATUS = TypeAdapter(LinkStatus)
#: A console topic's JetStream subjects (by :meth:`LiveBus.filter`'s kind).
_TOPIC_KINDS = {
    "commands": "event.commands",
    "passes": "event.passes",
    "events": "event.>",
    "alarms": "alarm",
    "link": "link",
    "telemetry": "telemetry",
}


def _json(doc: Any) -> bytes:
    return json.dumps(doc, separators=(",", ":")).encode()


class AcrossGrounds:
    """One ground's publishing to, and following of, the shared JetStream stream."""

    def __init__(self, bus: LiveBus, *, commanding: Callable[[], bool]) -> None:
        """``commanding``: whether this ground holds the command lease (its link status is
        the vehicle's; a standby's says only that no vehicle is connected to it)."""
        self.bus = bus
        self._commanding = commanding
        #: the last JetStream sequence handed to the hub's streams
        self.position = 0
        self._book: StreamBook | None = None
        self._early: list[tuple[int, str, bytes]] = []  # received before the hub was there
        self._unhook: list[Callable[[], None]] = []
        self.undecodable = 0

    @property
    def epoch(self) -> str:
        return self.bus.epoch

    async def open(self, publisher: Publisher) -> None:
        """Publish ``publisher``'s committed messages from now on, and follow the stream
        from its end (messages are held until :meth:`attach`)."""
        self.position = await self.bus.follow(self._received)
        self._unhook = [
            publisher.subscribe(self._publish_event),
            publisher.subscribe_frames(self._publish_frames),
            publisher.subscribe_alarms(self._publish_alarm),
        ]

    def attach(self, book: StreamBook) -> None:
        """Feed ``book`` (the hub's streams), first with what came before it was there."""
        self._book = book
        early, self._early = self._early, []
        for seq, subject, data in early:
            self._received(seq, subject, data)

    async def close(self) -> None:
        for unhook in self._unhook:
            unhook()
        self._unhook = []
        await self.bus.close()

    # -- publishing (the publisher's callbacks: on the event loop, never block) -------------

    def _publish_event(self, recorded: Recorded) -> None:
        doc = console_event(recorded)
        subject = self.bus.subject(f"event.{event_class(doc.kind)}", doc.pass_id)
        self.bus.publish(subject, doc.model_dump_json().encode())

    def _publish_frames(
        self, pass_id: str, frames: list[TelemetryFrame], reception_time_ns: int
    ) -> None:
        if not frames:
            return
        batch = telemetry_rows(frames, reception_time_ns)
        pass_id = canonical_pass(pass_id) or pass_id
        doc = {"pass_id": pass_id, "columns": batch.columns, "rows": batch.rows}
        self.bus.publish(self.bus.subject("telemetry", pass_id), _json(doc))

    def _publish_alarm(self, alarm: AlarmPublic) -> None:
        subject = self.bus.subject("alarm", canonical_pass(alarm.pass_id))
        self.bus.publish(subject, alarm.model_dump_json().encode())

    def publish_link(self, report: LinkReport) -> None:
        if self._commanding():
            doc = {"ground_time_ns": report.ground_time_ns, "status": asdict(report.status)}
            self.bus.publish(self.bus.subject("link", None), _json(doc))

    # -- following ------------------------------------------------------------------------

    def _received(self, seq: int, subject: str, data: bytes) -> None:
        if seq <= self.position:
            return  # sent again (the ordered consumer recreated after a gap)
        if self._book is None:
            self._early.append((seq, subject, data))
            return
        _, kind = self.bus.kind_of(subject)
        try:
            payload, pass_id = self._payload(kind, data)
        except Exception as exc:
            self.undecodable += 1
            log.warning("JetStream message %d on %s not understood: %r", seq, subject, exc)
            payload, pass_id = None, None
        book = self._book
        # delivered before the position moves: a stream it makes holds everything after
        # the previous position
        if isinstance(payload, ConsoleEvent):
            book.deliver_event(payload, None, seq)
        elif isinstance(payload, TelemetryRows):
            book.deliver_frames(pass_id, payload, None, seq)
        elif isinstance(payload, AlarmPublic):
            book.deliver_alarm(payload, seq)
        elif isinstance(payload, LinkReport):
            book.deliver_link(book.with_this_ground(payload), seq)
        self.position = seq

    @staticmethod
    def _payload(kind: str, data: bytes) -> tuple[Payload, str | None]:
        """The message's payload, and its pass (telemetry's)."""
        if kind.startswith("event."):
            return ConsoleEvent.model_validate_json(data), None
        if kind == "alarm":
            return AlarmPublic.model_validate_json(data), None
        doc = json.loads(data)
        if kind == "telemetry":
            rows = TelemetryRows(tuple(doc["columns"]), [tuple(r) for r in doc["rows"]])
            return rows, canonical_pass(doc["pass_id"])
        if kind == "link":
            status = _LINK_STATUS.validate_python(doc["status"])
            return LinkReport(doc["ground_time_ns"], status), None
        raise ValueError(f"unknown kind {kind!r}")

    # -- resuming -------------------------------------------------------------------------

    async def last_seq(self) -> int:
        return (await self.bus.bounds())[1]

    async def replay(
        self, stream: Stream, since: int, limit: int
    ) -> tuple[list[Message] | None, str]:
        """``stream``'s messages ``(since, stream.last_seq]`` read back from JetStream, or
        None and why not (the stream no longer holds them, more than ``limit``)."""
        kind = _TOPIC_KINDS[stream.topic]
        try:
            first, _ = await self.bus.bounds()
            if since + 1 < first:
                return None, f"seq {since + 1} is no longer held (JetStream's begins at {first})"
            subject = self.bus.filter(kind, stream.pass_id)
            found = await self.bus.read(subject, since, stream.last_seq, limit)
        except Exception as exc:
            log.exception("console replay of %s from JetStream failed", stream.topic)
            return None, f"the JetStream replay failed: {exc!r}"[:300]
        if found is None:
            return None, f"more than {limit} messages to replay"
        out = []
        for seq, subject, data in found:
            message = Message(seq, None, self._payload(self.bus.kind_of(subject)[1], data)[0])
            message.text = render(stream, message, None)
            out.append(message)
        return out, ""
