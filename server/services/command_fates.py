"""What the vehicle says became of a command, filed in the command record (docs/protocol.md):
:class:`CommandFates`, the link's routing of acknowledgements to their pass and stage.

- ``command_ack`` moves the command's stage (``received``, ``executed``, ``rejected`` with
  its reason, ``cancelled`` when a ``schedule_delete`` removed it) with the onboard time,
  never backwards (:func:`server.storage.stages.acked_stage`); a ``schedule_full`` refusal
  is transient (the vehicle did not keep the command; the runner sends it again): a
  ``command_deferred`` event, the stage left alone. An acknowledgement of a seq no pass
  holds is audited (``command_ack_unknown``).
- ``command_unknown`` expires the commands the vehicle never received whose tag has passed
  (:func:`server.storage.stages.expires_unknown`).

A seq belongs to the pass the runner registered it for (:meth:`CommandFates.expect`), else
to the newest pass that queued it. Acknowledgements are queued on the database worker in
order and not waited for (they share commits, and a run of them its statements:
:mod:`server.services.stage_writes`); the link tells the runner after filing.
"""

from __future__ import annotations

from sqlalchemy.orm import Session

from server.services.clock import Clock
from server.services.command_stages import set_command_stage
from server.services.dbworker import Database
from server.services.events import CommandDeferred, Recorded, event_job
from server.services.stage_writes import StageMove, StageWrites, newest_pass_of
from server.storage import repository as repo
from server.storage.stages import acked_stage, expires_unknown
from telemetry.wire import CommandAck, CommandUnknown

__all__ = ["CommandFates"]


class CommandFates:
    def __init__(self, *, db: Database, clock: Clock) -> None:
        self._db = db
        self._clock = clock
        self._writes = StageWrites(clock)
        #: seq -> pass, for acknowledgements (registered by the runner)
        self._command_pass: dict[int, str] = {}

    def expect(self, pass_id: str, seqs: list[int]) -> None:
        """Acknowledgements of these seqs belong to ``pass_id``."""
        for seq in seqs:
            self._command_pass[seq] = pass_id

    def _pass_of(self, session: Session, seq: int) -> str | None:
        key = self._command_pass.get(seq)
        return key if key is not None else newest_pass_of(session, seq)

    def file_ack(self, ack: CommandAck, actor: str) -> None:
        """Queue the stage write of one ``command_ack`` (not awaited)."""
        clock = self._clock
        reason = None if ack.reason is None else ack.reason.value
        stage = ack.stage.value
        filed = acked_stage(stage, reason)
        if filed is None:
            # Transient: the vehicle did not keep it, the runner sends it again.
            deferred = CommandDeferred(
                actor=actor, seq=ack.seq, reason=reason, detail_text=ack.detail
            )
            self._db.submit(event_job(deferred, clock))
            return
        # cancelled: the ground's clock (the stage times of storage/models.py)
        at_ns = clock.time_ns() if filed == "cancelled" else ack.onboard_time_ns
        move = StageMove(
            pass_id=self._command_pass.get(ack.seq),  # None: the newest pass that queued it
            seq=ack.seq,
            stage=filed,
            time_ns=at_ns,
            actor=actor,
            reason=reason,
            detail=ack.detail,
            acked=stage,
        )
        # Not awaited: acknowledgements queue behind each other in order, share commits
        # and, consecutive, their statements.
        self._db.submit(self._writes.job([move]))

    async def expire_unknown(self, message: CommandUnknown, actor: str) -> None:
        """The vehicle never received these: lost on the uplink; those whose tag has passed
        can no longer run (written, and waited for)."""
        clock = self._clock
        now_ns = clock.time_ns()

        def job(session: Session) -> list[Recorded]:
            events: list[Recorded] = []
            for seq in message.seqs:
                key = self._pass_of(session, seq)
                if key is None:
                    continue
                command = repo.get_command(session=session, pass_id=key, seq=seq)
                if not expires_unknown(
                    command.stage, command.execute_time_ns, message.onboard_time_ns
                ):
                    continue  # received after all, already final, or not due yet
                events += set_command_stage(
                    session,
                    clock=clock,
                    pass_id=key,
                    seq=seq,
                    stage="expired",
                    time_ns=now_ns,
                    actor=actor,
                    detail="never reached the vehicle before its tag",
                )
            return events

        await self._db.write(job)
