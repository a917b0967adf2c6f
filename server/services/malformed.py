"""What the ground does with messages from the spacecraft it cannot read: bounded work.

A noisy link (a relay that corrupts, vehicle software gone wrong, someone with the token)
can deliver hundreds of malformed messages a second. Each used to cost an ``error`` reply
and an audit row written before the next message was read, and at 391 a second the uplink
and the acknowledgements behind them starved. :class:`MalformedGuard` keeps that work
bounded, whatever the rate; it decides, :class:`~server.services.link.GroundLink` acts:

- **Counted, audited per kind per interval.** A message's kind is the ``type`` it claims
  (one of the protocol's, ``other`` for a type the protocol does not have, none when it
  could not be read) and the class of its refusal (``WireError.code``: ``not_json``,
  ``version``, ``unknown_type``, ``invalid``, ...), so there are a bounded number of kinds
  whatever the noise says. The first malformed message opens an interval of
  :attr:`MalformedPolicy.interval_s`; at its end (or when the connection goes) each kind
  seen is one audit row with its count, how many were answered, a sample reason and the
  times of the first and last (:meth:`MalformedGuard.take_interval`).
- **Answered at a bounded rate.** ``error`` replies leave at most
  :attr:`MalformedPolicy.replies_per_s` a second (a bucket of as many); the others are
  counted, and the next reply says how many went unanswered before it.
- **Noise never closes a link that still carries the real traffic.** A connection is
  closed (1008) only when its stream is unusable: nothing on it has decoded for at least
  :attr:`MalformedPolicy.interval_s` while more than :attr:`MalformedPolicy.unusable_after`
  malformed messages arrived in a row (``unusable stream: N malformed messages and nothing
  readable for T s``), audited; the vehicle reconnects, and the windowed uplink and the
  downlink's resends carry the pass across (docs/protocol.md). One message that decodes
  (any type, an ``error`` too) ends the run: a flood beside valid frames is dropped and
  counted, never a reason to close: closing it would turn noise into outages (at 400 a
  second for 30 s, 10 closes aborted a pass on PostgreSQL when they did).

``error`` messages from the vehicle are never answered (no ping-pong); they are tallied the
same way (one row per interval), and an unreadable one counts in the run of malformed ones.
Times are the injected clock's (ground monotonic s).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from server.services.clock import Clock
from server.services.events import Event, LinkErrorReceived, LinkErrorReplied
from telemetry.wire import SPACECRAFT_TYPES, WireError

__all__ = ["MalformedGuard", "MalformedPolicy", "Tally", "Verdict", "tally_events"]


@dataclass(frozen=True)
class MalformedPolicy:
    """The bounds (server/settings.py's ``malformed_*`` settings)."""

    #: ground s: one audit row per kind per interval; and how long a connection must have
    #: carried nothing readable before it can be found unusable
    interval_s: float = 5.0
    #: ``error`` replies a second at most (and a burst of as many)
    replies_per_s: float = 10.0
    #: more malformed messages than this in a row on one connection, nothing readable
    #: between them for at least ``interval_s``: the stream is unusable, closed
    unusable_after: int = 1000

    def __post_init__(self) -> None:
        if not self.interval_s > 0 or not self.replies_per_s >= 0 or not self.unusable_after >= 1:
            raise ValueError(f"malformed-message policy out of range: {self}")


@dataclass
class Tally:
    """One kind's messages within one interval."""

    ref_type: str | None
    code: str
    count: int
    replied: int
    sample_reason: str
    #: the first message's ``ref_type`` as it came (an ``error``'s: the type it names)
    sample_ref_type: str | None
    first_mono: float
    last_mono: float


@dataclass(frozen=True)
class Verdict:
    """What to do with one malformed message: the ``error`` reply's reason (None: no
    reply) and the close reason (None: keep the connection), with the run of malformed
    messages that closes it (its count, and ground s since its first)."""

    reply: str | None
    close: str | None = None
    run_count: int = 0
    run_s: float = 0.0


_KEEP = Verdict(None)


@dataclass
class _Bucket:
    rate: float
    tokens: float
    at: float

    def take(self, now: float) -> bool:
        self.tokens = min(self.rate, self.tokens + (now - self.at) * self.rate)
        self.at = now
        if self.tokens >= 1.0:
            self.tokens -= 1.0
            return True
        return False


@dataclass
class MalformedGuard:
    policy: MalformedPolicy = field(default_factory=MalformedPolicy)
    #: totals since the ground started (the link status)
    malformed: int = 0
    replied: int = 0
    unanswered: int = 0
    closes: int = 0
    by_kind: dict[str, int] = field(default_factory=dict)
    #: the open interval: its start (None: none open) and its tallies by kind
    interval_start: float | None = None
    _tallies: dict[tuple[str | None, str], Tally] = field(default_factory=dict)
    _bucket: _Bucket | None = None
    _unanswered_since_reply: int = 0
    #: the run of malformed messages with nothing readable between them: its connection
    #: (None: no run open), the time of its first and its count
    _run_conn: int | None = None
    _run_start: float = 0.0
    _run_count: int = 0

    @staticmethod
    def kind_of(ref_type: str | None, code: str) -> tuple[str | None, str]:
        """A bounded key: the claimed type only when the protocol has it."""
        if ref_type is not None and ref_type not in SPACECRAFT_TYPES:
            ref_type = "other"
        return ref_type, code

    def _tally(
        self, ref_type: str | None, code: str, reason: str, now: float, sample_ref: str | None
    ) -> Tally:
        if self.interval_start is None:
            self.interval_start = now
        key = self.kind_of(ref_type, code)
        tally = self._tallies.get(key)
        if tally is None:
            tally = self._tallies[key] = Tally(key[0], code, 0, 0, reason, sample_ref, now, now)
        tally.count += 1
        tally.last_mono = now
        label = f"{key[0] or '-'}:{code}"
        self.by_kind[label] = self.by_kind.get(label, 0) + 1
        return tally

    def readable(self, conn: int) -> None:
        """A message of connection ``conn`` decoded: its stream is usable, the run of
        malformed ones ends. Called for every good message: one comparison."""
        if conn == self._run_conn:
            self._run_conn = None

    def _unusable(self, conn: int, now: float) -> Verdict | None:
        if conn != self._run_conn:
            self._run_conn, self._run_start, self._run_count = conn, now, 0
        self._run_count += 1
        run_s = now - self._run_start
        if self._run_count > self.policy.unusable_after and run_s >= self.policy.interval_s:
            self.closes += 1
            n, self._run_conn = self._run_count, None
            reason = (
                f"unusable stream: {n} malformed messages and nothing readable for {run_s:.1f} s"
            )
            return Verdict(None, reason, n, run_s)
        return None

    def refused(self, conn: int, exc: WireError, reason: str, now: float) -> Verdict:
        """A message of connection ``conn`` the decoder refused with ``exc`` (``reason``,
        its text as it goes out) at ``now``."""
        self.malformed += 1
        code = "unreadable" if exc.ref_type == "error" else exc.code
        tally = self._tally(exc.ref_type, code, reason, now, exc.ref_type)
        closing = self._unusable(conn, now)
        if closing is not None:
            return closing  # not answered: the connection is closing
        if exc.ref_type == "error":
            return _KEEP  # never answered
        if self._bucket is None:
            rate = self.policy.replies_per_s
            self._bucket = _Bucket(rate, rate, now)
        if not self._bucket.take(now):
            self.unanswered += 1
            self._unanswered_since_reply += 1
            return _KEEP
        self.replied += 1
        tally.replied += 1
        skipped, self._unanswered_since_reply = self._unanswered_since_reply, 0
        if skipped:
            note = f" ({skipped} more malformed messages unanswered before this one)"
            reason = reason[: 500 - len(note)] + note
        return Verdict(reason[:500])

    def error_received(self, reason: str, ref_type: str | None, now: float) -> None:
        """A well-formed ``error`` from the vehicle (naming a message of ours of
        ``ref_type``): tallied, never answered; it decoded, so the caller reports it
        :meth:`readable` too."""
        self._tally("error", "received", reason, now, ref_type)

    def interval_end(self) -> float | None:
        """When the open interval ends (None: none open)."""
        if self.interval_start is None:
            return None
        return self.interval_start + self.policy.interval_s

    def take_interval(self) -> list[Tally]:
        """The open interval's tallies (one per kind), closing it."""
        tallies = list(self._tallies.values())
        self._tallies.clear()
        self.interval_start = None
        return tallies


def tally_events(tallies: list[Tally], actor: str, clock: Clock) -> list[Event]:
    """The audit events of one interval's tallies: ``link_error_received`` for the
    vehicle's ``error`` messages, ``link_error_replied`` for the others."""
    events: list[Event] = []
    for t in tallies:
        first, last = clock.time_ns_at(t.first_mono), clock.time_ns_at(t.last_mono)
        if t.ref_type == "error":
            events.append(
                LinkErrorReceived(
                    actor=actor,
                    reason=t.sample_reason,
                    ref_type=t.sample_ref_type if t.code == "received" else None,
                    code=t.code,
                    count=t.count,
                    first_time_ns=first,
                    last_time_ns=last,
                )
            )
        else:
            events.append(
                LinkErrorReplied(
                    actor=actor,
                    reason=t.sample_reason,
                    ref_type=t.sample_ref_type,
                    code=t.code,
                    count=t.count,
                    replied=t.replied,
                    first_time_ns=first,
                    last_time_ns=last,
                )
            )
    return events
