"""The ground's publish hook: what a transaction wrote, handed once it has committed to
whoever subscribed (the consoles' hub, the alarms, the operator's log lines, the Foxglove
live view, the consoles across grounds), typed: each event as a
:class:`~server.services.event_log.Recorded`, each alarm as written as its one model
(:class:`~telemetry.alarm.AlarmPublic`). The session factories the ground writes with
deliver to it when a transaction commits
(:func:`~server.services.event_log.publish_on_commit`); newly archived telemetry frames come
from the downlink once their batch has committed."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable, Iterable, Sequence
from typing import Any

from server.services.event_log import Recorded
from telemetry.alarm import AlarmPublic
from telemetry.wire import TelemetryFrame

__all__ = ["AlarmCallback", "EventCallback", "FrameCallback", "Publisher"]

log = logging.getLogger("hikoboshi.ground.db")


FrameCallback = Callable[[str, list[TelemetryFrame], int], None]
#: Gets each committed event, typed.
EventCallback = Callable[[Recorded], None]
#: Gets an alarm as written once it is committed.
AlarmCallback = Callable[[AlarmPublic], None]


class Publisher:
    """An in-process publish hook: subscribers get every event once it is committed, every
    newly archived telemetry frame (``pass_id, frames, reception_time_ns``), and every alarm
    as written. Callbacks run on the event loop the publisher was made on (or first
    subscribed from); a subscriber must not block; one that raises is logged and kept."""

    def __init__(self) -> None:
        self._subscribers: list[EventCallback] = []
        self._frame_subscribers: list[FrameCallback] = []
        self._alarm_subscribers: list[AlarmCallback] = []
        self._loop: asyncio.AbstractEventLoop | None = None
        self._bind()

    def _bind(self) -> None:
        if self._loop is None:
            with contextlib.suppress(RuntimeError):
                self._loop = asyncio.get_running_loop()

    def subscribe(self, callback: EventCallback) -> Callable[[], None]:
        self._bind()
        self._subscribers.append(callback)
        return lambda: self._subscribers.remove(callback)

    def subscribe_frames(self, callback: FrameCallback) -> Callable[[], None]:
        self._bind()
        self._frame_subscribers.append(callback)
        return lambda: self._frame_subscribers.remove(callback)

    def subscribe_alarms(self, callback: AlarmCallback) -> Callable[[], None]:
        self._bind()
        self._alarm_subscribers.append(callback)
        return lambda: self._alarm_subscribers.remove(callback)

    def deliver(self, items: Iterable[object]) -> None:
        """What a transaction wrote, once it has committed, from any thread: published on
        the event loop (at once when called there), in order."""
        items = list(items)
        loop = self._loop
        if loop is None or loop.is_closed():
            self.publish(items)
            return
        try:
            here = asyncio.get_running_loop()
        except RuntimeError:
            here = None
        if here is loop:
            self.publish(items)
        else:
            with contextlib.suppress(RuntimeError):  # closed meanwhile: no one listens
                loop.call_soon_threadsafe(self.publish, items)

    def publish(self, items: Iterable[object]) -> None:
        """Hand each item to its subscribers: an event (:class:`Recorded`) to the event
        subscribers, an alarm to the alarm subscribers (on the event loop)."""
        for item in items:
            if isinstance(item, Recorded):
                self._each(self._subscribers, item, item.kind)
            elif isinstance(item, AlarmPublic):
                self._each(self._alarm_subscribers, item, f"alarm {item.id}")
            else:
                raise TypeError(f"{type(item).__name__} is not published")

    @staticmethod
    def _each(callbacks: Sequence[Callable[[Any], None]], item: object, what: str) -> None:
        for callback in list(callbacks):
            try:
                callback(item)
            except Exception:
                log.exception("subscriber failed on %s", what)

    def publish_frames(
        self, pass_id: str, frames: list[TelemetryFrame], reception_time_ns: int
    ) -> None:
        for callback in list(self._frame_subscribers):
            try:
                callback(pass_id, frames, reception_time_ns)
            except Exception:
                log.exception("frame subscriber failed on pass %s", pass_id)
