"""The alarms of one pass as a state machine, pure (no clock, no database): readings of the
limit checker in, the changes to write and publish out (docs/alarms.md).

An :class:`AlarmBook` holds the pass's *listed* alarms (active: triggered, or cleared and
not yet acknowledged), one per quantity and channel, each the alarm's one model
(:class:`telemetry.alarm.AlarmPublic`), changed in place. :meth:`AlarmBook.observe` takes the
readings of one frame batch in frame order (a channel in a band, or a channel whose band
changed, as :meth:`telemetry.limits.FrameEvaluator.evaluate` reports them):

- a channel entering a band with no listed alarm raises a new alarm at that frame, or, with
  a ``persistence`` of N (the robot's ``[limits] persistence``, as COSMOS's limits have),
  at the N-th consecutive reading in a band (any band; a reading within limits starts the
  count again): a value flickering across a threshold for fewer than N samples at a time
  raises nothing. The same holds for reopening a cleared alarm;
- a band change of a triggered alarm is a severity change (escalation when it is worse than
  the worst so far: ``severity`` and ``limit`` follow);
- a channel back within limits clears the alarm (``current_severity`` None); cleared and
  acknowledged, it is no longer listed;
- a channel entering a band while its cleared alarm is still listed (not yet acknowledged)
  reopens that alarm; once cleared *and* acknowledged, a new crossing is a new alarm;
- a reading in the alarm's current band is an in-band update (count, worst and last value):
  the service writes those at most once per second.

Every change of band is appended to the alarm's ``timeline``
(:class:`~telemetry.alarm.AlarmTimelineEntryPublic`, at most
:data:`MAX_TIMELINE` entries: the first is kept, then the newest).
"""

from __future__ import annotations

import math
import uuid
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Literal, NamedTuple

from planner.limits import SEVERITY_RANK, Severity
from telemetry.alarm import AlarmDirection, AlarmPublic, AlarmSource, AlarmTimelineEntryPublic

__all__ = [
    "MAX_TIMELINE",
    "AlarmBook",
    "Change",
    "ChangeKind",
    "Observation",
    "QuantityInfo",
]

#: The most timeline entries an alarm keeps (a channel flickering across a threshold for
#: hours would otherwise grow its row without bound).
MAX_TIMELINE = 1000

ChangeKind = Literal["raised", "reopened", "severity", "cleared", "updated"]


class Observation(NamedTuple):
    """One channel's value at one frame (or link sample) and its band (None: within)."""

    quantity: str
    channel: str
    value: float | None
    severity: Severity | None
    frame_seq: int | None
    generation_time_ns: int | None


@dataclass(frozen=True)
class QuantityInfo:
    """What an alarm says of its quantity: label, unit, direction, and the threshold of a
    severity's band (None: the quantity has no such band)."""

    label: str
    unit: str
    direction: AlarmDirection
    threshold: Callable[[Severity], float | None]


def _finite(value: float | None) -> float | None:
    return None if value is None or not math.isfinite(value) else float(value)


def _mark(alarm: AlarmPublic, severity: Severity | None, o: Observation, now_ns: int) -> None:
    """Append a change of band to the alarm's timeline (the first entry kept, then the
    newest :data:`MAX_TIMELINE`)."""
    alarm.timeline.append(
        AlarmTimelineEntryPublic(
            severity=severity,
            generation_time_ns=o.generation_time_ns,
            time_ns=now_ns,
            frame_seq=o.frame_seq,
            value=_finite(o.value),
        )
    )
    if len(alarm.timeline) > MAX_TIMELINE:
        del alarm.timeline[1]


def _take(alarm: AlarmPublic, o: Observation) -> None:
    """Count a reading in a band: the last value, and the worst (for the direction)."""
    alarm.count += 1
    value = _finite(o.value)
    alarm.last_value = value
    if value is None:
        return
    worst = alarm.worst_value
    if worst is None or (value > worst if alarm.direction == "high" else value < worst):
        alarm.worst_value = value


@dataclass(frozen=True)
class Change:
    """An alarm the observation changed, and how (the first change of a batch wins:
    ``raised`` over ``severity`` over ``updated``)."""

    alarm: AlarmPublic
    kind: ChangeKind


#: Which change of an alarm a batch reports when it had several.
_PRECEDENCE: dict[ChangeKind, int] = {
    "raised": 5,
    "reopened": 4,
    "cleared": 3,
    "severity": 2,
    "updated": 1,
}


class AlarmBook:
    """The listed alarms of one pass (``pass_id`` None: of no pass), by quantity and
    channel; see the module docstring. ``info`` gives a quantity's label, unit, direction
    and thresholds (None: not a quantity this book knows; its readings are ignored);
    ``persistence``: the consecutive readings in a band that raise (or reopen) an alarm."""

    def __init__(
        self,
        pass_id: str | None,
        info: Callable[[str], QuantityInfo | None],
        *,
        source: AlarmSource = "limit",
        new_id: Callable[[], str] = lambda: str(uuid.uuid4()),
        persistence: int = 1,
    ) -> None:
        self.pass_id, self.source, self.persistence = pass_id, source, persistence
        self._info, self._new_id = info, new_id
        self.listed: dict[tuple[str, str], AlarmPublic] = {}
        #: consecutive readings in a band of the channels with no triggered alarm
        self._runs: dict[tuple[str, str], int] = {}

    def restore(self, alarms: Iterable[AlarmPublic]) -> None:
        """Take over alarms stored before (a restart): those still listed."""
        for alarm in alarms:
            if alarm.active:
                self.listed[(alarm.quantity, alarm.channel)] = alarm

    def observe(
        self,
        observations: Iterable[Observation],
        now_ns: int,
        detail: str | None = None,
        info: QuantityInfo | None = None,
    ) -> list[Change]:
        """Apply readings in frame order (``now_ns``: ground time); the alarms changed, one
        change each (the most telling of the batch), in the order first changed. ``detail``
        and ``info`` (instead of the book's own) describe the alarms raised."""
        changes: dict[str, Change] = {}

        def note(alarm: AlarmPublic, kind: ChangeKind) -> None:
            old = changes.get(alarm.id)
            if old is None or _PRECEDENCE[kind] > _PRECEDENCE[old.kind]:
                changes[alarm.id] = Change(alarm, kind)
            alarm.updated_time_ns = now_ns

        for o in observations:
            key = (o.quantity, o.channel)
            alarm = self.listed.get(key)
            if o.severity is None:
                self._runs.pop(key, None)
                if alarm is not None and alarm.state == "triggered":
                    self._clear(alarm, o, now_ns)
                    note(alarm, "cleared")
                    if not alarm.active:  # acknowledged while it was triggered
                        del self.listed[key]
                continue
            if (alarm is None or alarm.state == "cleared") and not self._persisted(key):
                continue
            if alarm is None:
                described = info or self._info(o.quantity)
                if described is None:
                    continue
                alarm = self._raise(o, described, now_ns, detail)
                self.listed[key] = alarm
                note(alarm, "raised")
            elif alarm.state == "cleared":
                alarm.state = "triggered"
                alarm.cleared_generation_time_ns = alarm.cleared_time_ns = None
                if detail is not None:
                    alarm.detail = detail
                self._band(alarm, o, now_ns, info)
                note(alarm, "reopened")
            elif o.severity != alarm.current_severity:
                self._band(alarm, o, now_ns, info)
                note(alarm, "severity")
            else:
                _take(alarm, o)
                note(alarm, "updated")
        return list(changes.values())

    def clear_all(self, now_ns: int, why: str, quantities: Iterable[str]) -> list[Change]:
        """Clear the triggered alarms of these quantities: no longer watched (``why``)."""
        wanted = set(quantities)
        out = []
        for alarm in list(self.listed.values()):
            if alarm.quantity in wanted and alarm.state == "triggered":
                o = Observation(alarm.quantity, alarm.channel, None, None, None, None)
                self._clear(alarm, o, now_ns)
                alarm.detail = why
                alarm.updated_time_ns = now_ns
                out.append(Change(alarm, "cleared"))
                if not alarm.active:
                    del self.listed[(alarm.quantity, alarm.channel)]
        return out

    def acknowledged(self, alarm_id: str, by: str, time_ns: int, comment: str | None) -> None:
        """An operator acknowledged a listed alarm: a cleared one is no longer listed."""
        for key, alarm in list(self.listed.items()):
            if alarm.id == alarm_id:
                alarm.acknowledged = True
                alarm.acknowledged_by = by
                alarm.acknowledged_time_ns = time_ns
                alarm.comment = comment
                alarm.updated_time_ns = max(alarm.updated_time_ns, time_ns)
                if not alarm.active:
                    del self.listed[key]

    def _persisted(self, key: tuple[str, str]) -> bool:
        """Count a reading in a band of a channel whose alarm is not triggered: True at the
        :attr:`persistence`-th in a row (the count starts again)."""
        run = self._runs.get(key, 0) + 1
        if run < self.persistence:
            self._runs[key] = run
            return False
        self._runs.pop(key, None)
        return True

    def holds(self, alarm_id: str) -> AlarmPublic | None:
        return next((a for a in self.listed.values() if a.id == alarm_id), None)

    # -- transitions -------------------------------------------------------------------------

    def _raise(
        self, o: Observation, info: QuantityInfo, now_ns: int, detail: str | None
    ) -> AlarmPublic:
        assert o.severity is not None
        value = _finite(o.value)
        alarm = AlarmPublic(
            id=self._new_id(),
            pass_id=self.pass_id,
            quantity=o.quantity,
            channel=o.channel,
            label=info.label,
            unit=info.unit,
            direction=info.direction,
            source=self.source,
            severity=o.severity,
            current_severity=o.severity,
            state="triggered",
            acknowledged=False,
            acknowledged_by=None,
            acknowledged_time_ns=None,
            comment=None,
            limit=_finite(info.threshold(o.severity)),
            trigger_value=value,
            worst_value=value,
            last_value=value,
            count=1,
            raised_frame_seq=o.frame_seq,
            raised_generation_time_ns=o.generation_time_ns,
            raised_time_ns=now_ns,
            updated_time_ns=now_ns,
            cleared_generation_time_ns=None,
            cleared_time_ns=None,
            timeline=[],
            detail=detail,
        )
        _mark(alarm, o.severity, o, now_ns)
        return alarm

    def _band(
        self, alarm: AlarmPublic, o: Observation, now_ns: int, info: QuantityInfo | None
    ) -> None:
        """The alarm enters another band (or the same again, reopened)."""
        assert o.severity is not None
        alarm.current_severity = o.severity
        _take(alarm, o)
        if SEVERITY_RANK[o.severity] > SEVERITY_RANK[alarm.severity]:
            alarm.severity = o.severity
            info = info or self._info(alarm.quantity)
            if info is not None:
                alarm.limit = _finite(info.threshold(o.severity))
        _mark(alarm, o.severity, o, now_ns)

    @staticmethod
    def _clear(alarm: AlarmPublic, o: Observation, now_ns: int) -> None:
        alarm.state = "cleared"
        alarm.current_severity = None
        alarm.cleared_generation_time_ns = o.generation_time_ns
        alarm.cleared_time_ns = now_ns
        if o.value is not None:
            alarm.last_value = _finite(o.value)
        _mark(alarm, None, o, now_ns)
