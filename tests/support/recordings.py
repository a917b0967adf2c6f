"""The short recording of the report, analysis and import tests: the cheap PTP plan flown
offline, with commands (stage times, one rejected), audit events and the meta of an aborted
pass; and any recording as MCAP bytes."""

from __future__ import annotations

import io

from planner.plan import Plan
from spacecraft.offline import fly_offline
from telemetry.mcap import write_mcap
from telemetry.recording import CommandRow, EventRow, PassRecording

#: A name that must be escaped in HTML and made safe in a file name.
SHORT_NAME = "<b>short</b> & PTP"


def _commands(plan: Plan, epoch_ns: int) -> tuple[CommandRow, ...]:
    out = []
    for seq in range(12):
        tag = epoch_ns + round(float(plan.command_times_s[seq]) * 1e9)
        rejected = seq == 11
        out.append(
            CommandRow(
                seq=seq,
                kind="joints",
                execute_time_ns=tag,
                payload={"joints_rad": plan.command_joints_rad[seq].tolist()},
                stage="rejected" if rejected else "executed",
                reject_reason="late" if rejected else None,
                stage_times_ns={
                    "queued": 1_000 + seq,
                    "released": tag - 6_000_000_000,
                    "sent": tag - 5_900_000_000,
                    "received": tag - 2_000_000_000,
                    "executed": None if rejected else tag,
                    "rejected": tag - 1_000_000_000 if rejected else None,
                    "expired": None,
                    "cancelled": None,
                },
            )
        )
    return tuple(out)


def mcap_bytes(recording: PassRecording) -> bytes:
    buffer = io.BytesIO()
    write_mcap(recording, buffer)
    return buffer.getvalue()


def short_recording_of(ptp_plan: Plan) -> PassRecording:
    """The short recording: ``ptp_plan`` flown offline (seed 1), with its commands, events
    and the meta of an aborted pass."""
    flight = fly_offline(ptp_plan, seed=1)
    epoch = flight.epoch_ns
    return PassRecording.from_frames(
        SHORT_NAME,
        ptp_plan,
        epoch,
        flight.frames,
        commands=_commands(ptp_plan, epoch),
        events=(
            EventRow(time_ns=5, kind="pass_scheduled", actor="otto", detail={"relay": "TDRS-W"}),
            EventRow(time_ns=9, kind="pass_aborted", actor="otto", detail={"why": "test"}),
        ),
        meta={
            "pass_id": "0d2b4c1e-0000-4000-8000-000000000001",
            "state": "aborted",
            "state_reason": "operator abort after A->B",
            "relay": "TDRS-W",
            "aos_time_ns": 1_000,
            "los_time_ns": 2_000_000_000_000,
        },
    )
