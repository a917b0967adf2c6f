"""A resumed pass after a gap: what the vehicle can still fly continuously, and the rest held
(docs/protocol.md, "Resuming after a gap").

A ground back after more than the lead window finds the vehicle's schedule run dry: the arm
reached the last joint command it was loaded with and holds that pose, and the commands
after it can no longer arrive before their tags. Sending the rest of the motion would ask
the arm to jump from the pose it holds to a pose of the plan far from it: the vehicle
refuses it (``out_of_limits``, checked from where its target stands), or, where the jump is
slow enough, flies a straight catch-up ramp the plan never predicted. So the ground holds:

- **What the vehicle has.** ``hello.last_command_seq`` is the highest seq the vehicle has
  received; seqs are given in tag order and sent in tag order, so every command of the pass
  above it is not on board (whatever its stored stage), and the vehicle's last loaded joint
  target is the last joint command at or below it: the **held pose**.
- **Lost.** A command not on board whose tag is within the uplink's arrival bound of onboard
  now (``delay + margin / 2``, :attr:`server.services.uplink.Uplink.arrival_ns`) can no
  longer reach the vehicle. "Now" is read on a clock a relayed stamp has confirmed: the
  hello places the onboard clock where it stood when it was *read*, behind on a ground still
  starting, so the resumed uplink (:class:`ResumedUplink`) sends nothing until a stamp
  (telemetry, the pong of the hello's ping) has come, or a round trip and
  :data:`CLOCK_CONFIRM_EXTRA_S` have passed; it decides then, in the step that sends, so
  a hello read late no longer makes it send late (a stamp read late still can:
  docs/protocol.md). It expires meanwhile what the
  hello's clock already finds lost: that clock is never ahead of the vehicle's.
- **The break.** The first lost command that changes what the vehicle does: a joint command
  off the held pose (more than :data:`REPEAT_TOLERANCE_RAD` on any joint), or any
  attitude-control command. Lost joint commands that repeat the held pose are harmless: the
  plan held that pose there, and so does the vehicle.
- **No break** (nothing lost, or only repeats of the held pose): today's nominal resume. The
  first command not on board can still arrive, at least ``margin / 2`` before its tag: the
  vehicle ramps to it from where its target stands, no faster than the plan.
- **A break**: every command not on board that could still be sent (its tag beyond the
  arrival bound) is **withheld**: it leaves the uplink, never sent, and is ``cancelled`` at
  once with the reason (``held after a restart: seq ...``), in one ``commands_cancelled``
  event. The lost ones expire as the uplink's own rule has it (or, sent before the restart
  and never received, are asked about after LOS and expire). The vehicle keeps holding the
  pose (and the attitude-control mode) it was last loaded with; the pass runs to its LOS
  and ends ``complete, degraded: ... expired, ... cancelled``.

Nothing is re-planned: the planner could start a new motion from the held pose, but that is
a new plan, checked and started by an operator (:mod:`server.services.pass_states`).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from sqlalchemy.orm import Session

from server.services.clock import Clock
from server.services.command_stages import cancel_commands
from server.services.dbworker import Database
from server.services.event_log import Recorded
from server.services.link import GroundLink
from server.services.pass_states import command_from_record, uplink_timing
from server.services.recovery import UnfinishedPass
from server.services.tracker import CommandTracker
from server.services.uplink import Uplink, UplinkCommand
from server.settings import Settings
from server.storage.models import CommandRecord

__all__ = [
    "CLOCK_CONFIRM_EXTRA_S",
    "REPEAT_TOLERANCE_RAD",
    "Hold",
    "ResumedUplink",
    "hold_after_gap",
]

log = logging.getLogger("hikoboshi.ground.continuity")

#: A joint command within this of the held pose on every joint repeats it (rad).
REPEAT_TOLERANCE_RAD = 1e-6
#: Ground s beyond the relay's round trip a resumed uplink waits after the hello for the
#: onboard clock's first relayed stamp, and between its looks (our choice).
CLOCK_CONFIRM_EXTRA_S = 1.0
CLOCK_CONFIRM_POLL_S = 0.05


@dataclass(frozen=True)
class Hold:
    """A resumed pass whose motion the vehicle can no longer fly continuously."""

    #: the last joint command on board: its pose is the one the vehicle holds (None: no
    #: joint command of the pass reached the vehicle)
    held_seq: int | None
    #: the first lost command that changes what the vehicle does
    break_seq: int
    #: the commands never to be sent
    withheld: tuple[int, ...]
    reason: str


def _joints(record: CommandRecord) -> list[float]:
    return [float(v) for v in record.payload["joints_rad"]]


def _repeats(record: CommandRecord, held: CommandRecord | None) -> bool:
    if record.kind != "joints" or held is None:
        return False
    pairs = zip(_joints(record), _joints(held), strict=True)
    return all(abs(a - b) <= REPEAT_TOLERANCE_RAD for a, b in pairs)


def hold_after_gap(
    commands: Sequence[CommandRecord],
    *,
    onboard_ns: int,
    last_command_seq: int,
    arrival_ns: int,
) -> Hold | None:
    """The hold of a resumed pass's ``commands`` (all of them, any stage), or None to resume
    as nominal (see the module docstring): ``onboard_ns`` the onboard clock now,
    ``last_command_seq`` the vehicle's (its ``hello``), ``arrival_ns`` the uplink's arrival
    bound."""
    ordered = sorted(commands, key=lambda r: (r.execute_time_ns, r.seq))
    held: CommandRecord | None = None
    broken: CommandRecord | None = None
    lost_until_ns = onboard_ns + arrival_ns
    for r in ordered:
        if r.seq <= last_command_seq:
            if r.kind == "joints":
                held = r
            continue
        if r.execute_time_ns > lost_until_ns:
            break
        if not _repeats(r, held):
            broken = r
            break
    if broken is None:
        return None
    withheld = tuple(
        r.seq
        for r in ordered
        if r.seq > last_command_seq
        and r.execute_time_ns > lost_until_ns
        and r.stage not in ("executed", "rejected", "expired", "cancelled")
    )
    first_tag_ns = ordered[0].execute_time_ns
    at_s = (broken.execute_time_ns - first_tag_ns) / 1e9
    pose = "no pose of the pass" if held is None else f"the pose of seq {held.seq}"
    what = "moves the arm" if broken.kind == "joints" else "changes attitude control"
    reason = (
        f"held after a restart: seq {broken.seq} (t = {at_s:.2f} s) can no longer reach the "
        f"vehicle and {what}; the vehicle holds {pose}, the rest is not sent"
    )
    return Hold(None if held is None else held.seq, broken.seq, withheld, reason)


def _cancel_job(pass_id: str, hold: Hold, clock: Clock) -> Callable[[Session], list[Recorded]]:
    def job(session: Session) -> list[Recorded]:
        return cancel_commands(
            session,
            clock=clock,
            pass_id=pass_id,
            seqs=list(hold.withheld),
            time_ns=clock.time_ns(),
            actor="ground",
            reason=hold.reason,
            from_time_ns=None,
        )

    return job


class ResumedUplink(Uplink):
    """The uplink of a resumed pass: nothing goes up until a relayed stamp has confirmed
    the onboard clock (at most :data:`CLOCK_CONFIRM_EXTRA_S` beyond a
    round trip after the hello); then, once, :func:`hold_after_gap` on that clock, and what
    it withholds is cancelled and leaves the uplink."""

    def __init__(
        self,
        p: UnfinishedPass,
        link: GroundLink,
        settings: Settings,
        db: Database,
        clock: Clock,
        tracker: CommandTracker,
    ) -> None:
        """The uplink of the resumed pass ``p`` (its spacecraft back): its commands not
        final; what the earlier process sent and the vehicle did not acknowledge is owed
        again at once (:meth:`~server.services.uplink.Uplink.restore`)."""
        commands = [command_from_record(r) for r in p.pending]
        super().__init__(commands, **uplink_timing(settings, link))
        self._pass, self._link, self._db, self._clock, self._tracker = p, link, db, clock, tracker
        self._waiting_since: float | None = None
        #: the decision, once made (None before, or when nothing is held)
        self.hold: Hold | None = None
        self.decided = False
        self.restore(p.transmitted)

    def _ready(self, onboard_ns: int) -> bool:
        """Whether the hold is decided (deciding it now if the clock allows)."""
        if self.decided or self.stopped:
            return True
        link, now = self._link, self._clock.monotonic()
        if self._waiting_since is None:
            self._waiting_since = now
        if not link.connected:
            return False
        round_trip_s = 2 * self.one_way_delay_s / self.time_scale
        if not link.clock_confirmed and now - self._waiting_since < (
            round_trip_s + CLOCK_CONFIRM_EXTRA_S
        ):
            return False
        self.decided = True
        self.hold = hold_after_gap(
            self._pass.commands,
            onboard_ns=onboard_ns,
            last_command_seq=link.last_command_seq,
            arrival_ns=self.arrival_ns,
        )
        if self.hold is not None:
            hold, pass_id = self.hold, self._pass.id
            log.warning(
                "pass %s: %d commands withheld: %s", pass_id, len(hold.withheld), hold.reason
            )
            if hold.withheld:
                self.withhold(set(hold.withheld))
                self._db.submit(_cancel_job(pass_id, hold, self._clock))
                self._tracker.cancelled(hold.withheld)
        return True

    def expire(self, onboard_ns: int) -> list[UplinkCommand]:
        self._ready(onboard_ns)
        # before the stamp too: a hello read late puts the clock behind, never ahead, so what
        # it finds lost is lost (a pass resumed after its last tag expires at once)
        return super().expire(onboard_ns)

    def due(self, mono: float, onboard_ns: int) -> list[UplinkCommand]:
        return super().due(mono, onboard_ns) if self._ready(onboard_ns) else []

    def next_wake(self, link_mono_at: Any) -> float:
        wake = super().next_wake(link_mono_at)
        if not self.decided and not self.stopped:
            wake = min(wake, self._clock.monotonic() + CLOCK_CONFIRM_POLL_S)
        return wake
