r"""The stage rules of a command, defined once (docs/protocol.md).

    queued -> released -> sent -> received -> executed
                                          \-> rejected (reason)
    queued | released | sent | received -> cancelled (abort: deleted from the schedule;
                                              on-board safing: dropped, reason safing)
    queued | released | sent -> expired (could not reach the vehicle before its tag)

A stage only moves to a higher rank (:data:`STAGE_RANK`): acknowledgements cross on the
link. The vehicle's own word beats the ground's inference: a command the ground took as
lost (``expired``) or as deleted (``cancelled``) that the vehicle then reports
``executed`` or ``rejected`` is what the vehicle says.

Every "is it final" question of the ground (the runner's tracker, the pass summary, the
repository's cancel, the console) is answered from :data:`FINAL_STAGES`, derived here from
the ranks. This module lives in storage (the lowest layer) so that the repository can use it;
:mod:`server.services.command_stages` re-exports it.
"""

from __future__ import annotations

from server.storage.models import COMMAND_STAGES

__all__ = [
    "AWAITING_ACK_STAGES",
    "FINAL_STAGES",
    "OPEN_STAGES",
    "STAGE_RANK",
    "UNRECEIVED_STAGES",
    "acked_stage",
    "expires_unknown",
    "is_final",
    "moves",
]

#: A stage only ever moves to a higher rank; those of the highest rank end a command.
STAGE_RANK = {
    "queued": 0,
    "released": 1,
    "sent": 2,
    "received": 3,
    "executed": 4,
    "rejected": 4,
    "expired": 4,
    "cancelled": 4,
}
if set(STAGE_RANK) != set(COMMAND_STAGES):  # pragma: no cover - a model change
    raise RuntimeError("every command stage needs a rank")
_FINAL_RANK = max(STAGE_RANK.values())
#: The stages that end a command: nothing but the vehicle's own word moves it again.
FINAL_STAGES = tuple(stage for stage in COMMAND_STAGES if STAGE_RANK[stage] == _FINAL_RANK)
#: Not final: the command's fate is still open.
OPEN_STAGES = tuple(stage for stage in COMMAND_STAGES if stage not in FINAL_STAGES)
#: Transmitted (or being) and not final: an acknowledgement is outstanding.
AWAITING_ACK_STAGES = tuple(s for s in OPEN_STAGES if STAGE_RANK[s] >= STAGE_RANK["released"])
#: Not (yet) known to be on board.
UNRECEIVED_STAGES = tuple(s for s in OPEN_STAGES if STAGE_RANK[s] < STAGE_RANK["received"])
#: Inferred final stages the vehicle's own report replaces.
_INFERRED = ("expired", "cancelled")
_VEHICLE_FINAL = ("executed", "rejected")


def is_final(stage: str) -> bool:
    return stage in FINAL_STAGES


def moves(current: str, stage: str) -> bool:
    """Whether a command at ``current`` moves to ``stage``: only forwards, or the vehicle's
    own final word over the ground's inference."""
    overrules = current in _INFERRED and stage in _VEHICLE_FINAL
    return STAGE_RANK[stage] > STAGE_RANK[current] or overrules


def acked_stage(stage: str, reason: str | None) -> str | None:
    """The stage a ``command_ack`` files (``stage``, its ``reason``): ``cancelled`` when a
    ``schedule_delete`` removed the command or the vehicle's on-board safing dropped or
    refused it (reason ``safing``); None for a ``schedule_full`` refusal, which is
    transient (the vehicle did not keep the command; the runner sends it again)."""
    if reason == "schedule_full":
        return None
    return "cancelled" if reason in ("cancelled", "safing") else stage


def expires_unknown(stage: str, tag_ns: int, onboard_time_ns: int) -> bool:
    """Whether a command the vehicle answered ``command_unknown`` about (at
    ``onboard_time_ns``) is now ``expired``: never received, and its tag has passed (one not
    due yet is still sent)."""
    return stage in UNRECEIVED_STAGES and tag_ns <= onboard_time_ns
