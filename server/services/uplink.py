"""The windowed, acknowledged uplink of one pass's time-tagged commands (docs/protocol.md).

The idea of CCSDS COP-1 (a sliding window, retransmission until acknowledged) applied to an
onboard time-based schedule (the idea of ECSS PUS service 11): the ground keeps the
vehicle's schedule loaded up to a *lead window* ahead of the onboard clock, and sends each
command again until the vehicle acknowledges it, as long as it can still arrive before its
tag. The 4 Hz cadence is the plan's and the vehicle's; the ground only keeps the window
filled, so a ground stalled for seconds (GIL, database, garbage collector) delays nothing
that was loaded ahead.

This module is pure bookkeeping, driven by the runner with the times it reads from its
injected clock (``mono``: the ground's monotonic seconds; ``onboard_ns``: the ground's
estimate of the onboard clock):

- **Admission** (:meth:`Uplink.due`): the next command never sent goes up once its tag is
  within the lead window of the onboard clock, while the commands sent and not yet due
  onboard are fewer than the vehicle's schedule capacity, and while it can still arrive:
  its tag more than (one-way delay + half the uplink margin) ahead. A command that can no
  longer arrive and was never sent is **expired** (:meth:`Uplink.expire`).
- **Retransmission**: a command sent and not acknowledged goes again when its timer runs
  out, as long as it can still arrive. The timer is the round trip measured as RFC 6298
  does (smoothed RTT and variance, in ground seconds; Karn's rule: only acknowledgements of
  commands sent once are samples), starting from the relay's nominal round trip, never
  below it. The timer does not back off: the relay's losses are random, not congestion,
  and a command has only its lead window's worth of tries (COP-1's timer is fixed too);
  at 40x a doubled timer left a command six copies over 120 s, all lost in one run under
  20 % loss. It never runs past the command's *last chance*: the last instant
  a copy can still arrive in time (one-way delay + half the margin before its tag). A
  timer that would run out after it runs out at the last chance instead, so every
  command gets one more copy as late as it can still help.
- **Acknowledgement** (:meth:`Uplink.on_ack`): ``received`` (or any later word of the
  vehicle on it: executed, rejected, cancelled) ends the retransmission of that command; a
  ``schedule_full`` refusal does not (the vehicle did not keep it).
"""

from __future__ import annotations

import bisect
import heapq
import math
from dataclasses import dataclass
from typing import Any

from telemetry.uplink import Command

__all__ = ["RttEstimator", "Uplink", "UplinkCommand"]

#: Ground seconds the retransmission timeout allows beyond the nominal round trip.
RTO_FLOOR_EXTRA_S = 0.1
#: The longest retransmission timeout (ground s).
RTO_MAX_S = 60.0
#: Ground seconds the first timeout allows beyond the nominal round trip, before any sample.
RTO_INITIAL_EXTRA_S = 0.5
#: The last-chance copy goes this many onboard seconds before the last instant it could.
LAST_CHANCE_GUARD_S = 0.25


class RttEstimator:
    """RFC 6298 round-trip estimator, in ground seconds, with a floor at the relay's nominal
    round trip plus :data:`RTO_FLOOR_EXTRA_S`."""

    def __init__(self, nominal_rtt_s: float) -> None:
        self.floor_s = nominal_rtt_s + RTO_FLOOR_EXTRA_S
        self.srtt_s: float | None = None
        self.rttvar_s: float | None = None
        self.rto_s = min(RTO_MAX_S, nominal_rtt_s + RTO_INITIAL_EXTRA_S)
        self.samples = 0

    def sample(self, rtt_s: float) -> None:
        if rtt_s < 0:
            return
        if self.srtt_s is None or self.rttvar_s is None:
            self.srtt_s, self.rttvar_s = rtt_s, rtt_s / 2
        else:
            self.rttvar_s = 0.75 * self.rttvar_s + 0.25 * abs(self.srtt_s - rtt_s)
            self.srtt_s = 0.875 * self.srtt_s + 0.125 * rtt_s
        self.samples += 1
        self.rto_s = min(RTO_MAX_S, max(self.floor_s, self.srtt_s + 4 * self.rttvar_s))


@dataclass
class UplinkCommand:
    command: Command
    transmissions: int = 0
    first_sent_mono: float | None = None
    last_sent_mono: float | None = None
    timer_mono: float | None = None  # next retransmission due
    acked: bool = False
    #: onboard time of the vehicle's first word on it (its ``received``)
    ack_onboard_ns: int | None = None
    expired: bool = False

    @property
    def seq(self) -> int:
        return self.command.seq

    @property
    def tag_ns(self) -> int:
        return self.command.execute_time_ns


class Uplink:
    """The uplink state of one pass (see the module docstring)."""

    def __init__(
        self,
        commands: list[Command],
        *,
        one_way_delay_s: float,
        margin_s: float,
        lead_window_s: float,
        capacity: int,
        time_scale: float,
    ) -> None:
        ordered = sorted(commands, key=lambda c: (c.execute_time_ns, c.seq))
        self.commands = [UplinkCommand(c) for c in ordered]
        self._tags = [c.execute_time_ns for c in ordered]
        self.by_seq = {c.seq: c for c in self.commands}
        self._next = 0  # index of the first command never sent
        self._timers: list[tuple[float, int]] = []  # (due mono, seq)
        self.one_way_delay_s = one_way_delay_s
        self.margin_s = margin_s
        self.lead_window_ns = round(lead_window_s * 1e9)
        self.capacity = capacity
        self.time_scale = time_scale
        self.rtt = RttEstimator(2 * one_way_delay_s / time_scale)
        self.retransmissions = 0
        self.schedule_full_refusals = 0
        self.stopped = False

    # -- rules ---------------------------------------------------------------------------

    @property
    def arrival_ns(self) -> int:
        """A command must be at least this far ahead of its tag when sent (onboard ns)."""
        return round((self.one_way_delay_s + self.margin_s / 2) * 1e9)

    def can_arrive(self, cmd: UplinkCommand, onboard_ns: int) -> bool:
        return cmd.tag_ns - onboard_ns > self.arrival_ns

    def onboard_load(self, onboard_ns: int) -> int:
        """Commands sent (or being sent) whose tag is still ahead: what the schedule holds
        at most."""
        return max(0, self._next - bisect.bisect_right(self._tags, onboard_ns))

    # -- the runner's questions ----------------------------------------------------------

    def _arm(self, cmd: UplinkCommand, due: float) -> None:
        cmd.timer_mono = due
        heapq.heappush(self._timers, (due, cmd.seq))

    def restore(self, sent: dict[int, tuple[int, bool]]) -> None:
        """Restart recovery: ``sent`` maps the seqs an earlier process sent to (their
        transmissions, whether the vehicle acknowledged them). The unacknowledged ones are
        owed again at once (the vehicle answers a copy of what it holds with its stored
        acknowledgement); commands are admitted in tag order, so the never-sent ones are
        those after the last one sent."""
        last = -1
        for i, cmd in enumerate(self.commands):
            if cmd.seq in sent:
                transmissions, acked = sent[cmd.seq]
                cmd.transmissions = max(1, transmissions)
                cmd.acked = acked
                last = i
        self._next = last + 1
        for cmd in self.commands[: self._next]:
            if not cmd.acked:
                self._arm(cmd, -math.inf)

    def expire(self, onboard_ns: int) -> list[UplinkCommand]:
        """Never-sent commands (and sent ones never acknowledged that were owed a first
        transmission after a restart) that can no longer arrive before their tag."""
        out = []
        while self._next < len(self.commands):
            cmd = self.commands[self._next]
            if self.can_arrive(cmd, onboard_ns):
                break
            cmd.expired = True
            out.append(cmd)
            self._next += 1
        return out

    def due(self, mono: float, onboard_ns: int) -> list[UplinkCommand]:
        """What to send now: retransmissions whose timer ran out, then new commands the
        window admits (see the module docstring). The caller sends them in this order and
        reports each with :meth:`sent`."""
        out: list[UplinkCommand] = []
        timers = self._timers
        while timers and timers[0][0] <= mono:
            due, seq = heapq.heappop(timers)
            cmd = self.by_seq[seq]
            if cmd.acked or cmd.expired or due != cmd.timer_mono:
                continue  # done, or a timer since re-armed
            cmd.timer_mono = None
            if self.can_arrive(cmd, onboard_ns):
                out.append(cmd)
            # else: too late to arrive; what became of it is asked at LOS
        if self.stopped:
            return []
        horizon = onboard_ns + self.lead_window_ns
        load = self.onboard_load(onboard_ns)
        while self._next < len(self.commands) and load < self.capacity:
            cmd = self.commands[self._next]
            if cmd.tag_ns > horizon:
                break
            if not self.can_arrive(cmd, onboard_ns):
                break  # expire() takes it
            out.append(cmd)
            self._next += 1
            load += 1
        return out

    def sent(self, cmd: UplinkCommand, mono: float, onboard_ns: int) -> bool:
        """``cmd`` went on the socket at ``mono`` (the onboard clock reading ``onboard_ns``
        then); whether it was a retransmission."""
        again = cmd.transmissions > 0
        cmd.transmissions += 1
        if cmd.first_sent_mono is None:
            cmd.first_sent_mono = mono
        cmd.last_sent_mono = mono
        if again:
            self.retransmissions += 1
        if not cmd.acked:
            due = mono + self.rtt.rto_s
            last_chance_ns = cmd.tag_ns - self.arrival_ns - round(LAST_CHANCE_GUARD_S * 1e9)
            last_chance = mono + (last_chance_ns - onboard_ns) / 1e9 / self.time_scale
            if due > last_chance > mono:
                due = last_chance
            self._arm(cmd, due)
        return again

    def unsent(self, cmd: UplinkCommand) -> None:
        """The socket refused ``cmd`` (no link): it is owed again at once."""
        if cmd.transmissions == 0 and self._next > 0 and self.commands[self._next - 1] is cmd:
            self._next -= 1
        else:
            self._arm(cmd, -math.inf)

    def on_ack(self, seq: int, reason: str | None, onboard_ns: int, mono: float) -> bool:
        """The vehicle's word on ``seq``: whether it was the first (the command is then
        acknowledged)."""
        cmd = self.by_seq.get(seq)
        if cmd is None:
            return False
        if reason == "schedule_full":
            self.schedule_full_refusals += 1
            return False  # not kept onboard: its timer sends it again
        if cmd.acked:
            return False
        cmd.acked = True
        cmd.ack_onboard_ns = onboard_ns
        if cmd.transmissions == 1 and cmd.last_sent_mono is not None:
            self.rtt.sample(mono - cmd.last_sent_mono)  # Karn: unambiguous samples only
        return True

    def next_wake(self, link_mono_at: Any) -> float:
        """The ground monotonic instant of the next thing to do: a retransmission timer, or
        the next command entering the lead window (``link_mono_at`` maps an onboard time to
        the ground's monotonic clock)."""
        times = [t for t, seq in self._timers[:1]]
        if self._next < len(self.commands) and not self.stopped:
            cmd = self.commands[self._next]
            times.append(link_mono_at(cmd.tag_ns - self.lead_window_ns))
            # and when it would expire, if it cannot go before
            times.append(link_mono_at(cmd.tag_ns - self.arrival_ns))
        return min(times) if times else math.inf

    # -- state ---------------------------------------------------------------------------

    @property
    def all_sent(self) -> bool:
        return self._next >= len(self.commands)

    def unacked(self) -> list[UplinkCommand]:
        return [c for c in self.commands[: self._next] if not c.acked and not c.expired]

    def never_sent(self) -> list[UplinkCommand]:
        return [c for c in self.commands if c.transmissions == 0 and not c.expired]

    def sent_commands(self) -> list[UplinkCommand]:
        return [c for c in self.commands if c.transmissions > 0]

    def withhold(self, seqs: set[int]) -> None:
        """Never send these (commands not yet sent by this uplink, the last in tag order:
        :mod:`server.services.continuity`): they leave the uplink."""
        keep = [c for c in self.commands if c.seq not in seqs]
        self._next = sum(1 for c in self.commands[: self._next] if c.seq not in seqs)
        self.commands, self._tags = keep, [c.tag_ns for c in keep]
        self.by_seq = {c.seq: c for c in keep}
        self._timers = [(due, seq) for due, seq in self._timers if seq in self.by_seq]
        heapq.heapify(self._timers)

    def stop(self) -> None:
        """Send nothing more (abort)."""
        self._timers.clear()
        for c in self.commands:
            c.timer_mono = None
        self.stopped = True

    def fill_margins_s(self) -> list[float]:
        """Onboard s between each acknowledged command's ``received`` and its tag."""
        return [
            (c.tag_ns - c.ack_onboard_ns) / 1e9
            for c in self.commands
            if c.ack_onboard_ns is not None
        ]

    def status(self, onboard_ns: int | None) -> dict[str, Any]:
        sent = self._next
        acked = sum(1 for c in self.commands if c.acked)
        margins = self.fill_margins_s()
        return {
            "commands": len(self.commands),
            "sent": sent,
            "acknowledged": acked,
            "in_flight": sum(1 for c in self.commands[:sent] if not c.acked and c.transmissions),
            "expired": sum(1 for c in self.commands if c.expired),
            "retransmissions": self.retransmissions,
            "schedule_full_refusals": self.schedule_full_refusals,
            "onboard_load": None if onboard_ns is None else self.onboard_load(onboard_ns),
            "capacity": self.capacity,
            "lead_window_s": self.lead_window_ns / 1e9,
            "rto_s": self.rtt.rto_s,
            "srtt_s": self.rtt.srtt_s,
            "min_fill_margin_s": min(margins) if margins else None,
        }
