"""The consoles' publish hook: committed events, newly archived telemetry frames and alarms
as written, handed to whoever subscribed (the consoles' hub, the alarms, the Foxglove live
view). The database worker (:mod:`server.services.dbworker`) publishes after each commit."""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

from telemetry.alarm import AlarmPublic
from telemetry.wire import TelemetryFrame

__all__ = ["AlarmCallback", "FrameCallback", "Publisher"]

log = logging.getLogger("hikoboshi.ground.db")


FrameCallback = Callable[[str, list[TelemetryFrame], int], None]
#: Gets an alarm's JSON document (docs/alarms.md) once it is committed.
AlarmCallback = Callable[[AlarmPublic], None]


class Publisher:
    """An in-process publish hook for the consoles: subscribers get every event dict once it
    is committed, and every newly archived telemetry frame (``pass_id, frames,
    reception_time_ns``), and every alarm as written (its document). A subscriber must not
    block; one that raises is logged and kept."""

    def __init__(self) -> None:
        self._subscribers: list[Callable[[dict[str, Any]], None]] = []
        self._frame_subscribers: list[FrameCallback] = []
        self._alarm_subscribers: list[AlarmCallback] = []

    def subscribe(self, callback: Callable[[dict[str, Any]], None]) -> Callable[[], None]:
        self._subscribers.append(callback)
        return lambda: self._subscribers.remove(callback)

    def subscribe_frames(self, callback: FrameCallback) -> Callable[[], None]:
        self._frame_subscribers.append(callback)
        return lambda: self._frame_subscribers.remove(callback)

    def subscribe_alarms(self, callback: AlarmCallback) -> Callable[[], None]:
        self._alarm_subscribers.append(callback)
        return lambda: self._alarm_subscribers.remove(callback)

    def publish_alarms(self, alarms: list[AlarmPublic]) -> None:
        for alarm in alarms:
            for callback in list(self._alarm_subscribers):
                try:
                    callback(alarm)
                except Exception:
                    log.exception("alarm subscriber failed on %s", alarm.id)

    def publish_frames(
        self, pass_id: str, frames: list[TelemetryFrame], reception_time_ns: int
    ) -> None:
        for callback in list(self._frame_subscribers):
            try:
                callback(pass_id, frames, reception_time_ns)
            except Exception:
                log.exception("frame subscriber failed on pass %s", pass_id)

    def publish(self, events: list[dict[str, Any]]) -> None:
        for event in events:
            for callback in list(self._subscribers):
                try:
                    callback(event)
                except Exception:
                    log.exception("event subscriber failed on %s", event.get("kind"))
