"""Importing a recording into the database: everything stored, exactly, in one transaction;
on SQLite and PostgreSQL (``session`` from tests/server/conftest.py)."""

from __future__ import annotations

import dataclasses

import pytest
from sqlalchemy.orm import Session

from server.api.errors import status_of
from server.services import imports
from server.services.imports import InvalidRecording, store_recording
from server.services.recordings import load_recording
from server.storage import repository as repo
from telemetry.recording import FRAME_ARRAYS, PassRecording
from tests.support.archive import row_counts


def test_a_stored_recording_loads_back_exactly(
    session: Session, short_recording: PassRecording
) -> None:
    pass_id = store_recording(session, short_recording, "otto", source="test", now_ns=123)
    record = repo.get_pass(session=session, pass_id=pass_id)
    assert (record.name, record.state, record.state_reason, record.relay) == (
        short_recording.name,
        "aborted",
        "operator abort after A->B",
        "TDRS-W",
    )
    assert (record.aos_time_ns, record.los_time_ns) == (1_000, 2_000_000_000_000)
    gen = short_recording.frames.generation_time_ns
    assert record.telemetry_start_ns == gen[0] and record.telemetry_end_ns == gen[-1] + 1

    back = load_recording(session=session, pass_id=pass_id)
    assert back.name == short_recording.name and back.epoch_ns == short_recording.epoch_ns
    assert back.plan.to_json() == short_recording.plan.to_json()
    for name in FRAME_ARRAYS:
        got, want = getattr(back.frames, name), getattr(short_recording.frames, name)
        if name == "acs_mode":
            assert got.tolist() == want.tolist()
        else:  # bit for bit: the analyses of an imported pass must equal the original's
            assert got.dtype == want.dtype and got.tobytes() == want.tobytes(), name
    assert back.commands == short_recording.commands
    assert back.commands[11].stage == "rejected" and back.commands[11].reject_reason == "late"
    kinds = [e.kind for e in back.events]
    assert kinds == ["pass_scheduled", "pass_aborted", "pass_imported"]
    imported = back.events[-1]
    assert imported.actor == "otto" and imported.time_ns == 123
    assert imported.detail["original_pass_id"] == short_recording.meta["pass_id"]
    assert imported.detail["frames"] == len(short_recording.frames)


def test_a_recording_without_meta_becomes_a_complete_pass(
    session: Session, short_recording: PassRecording
) -> None:
    bare = dataclasses.replace(short_recording, meta={"state": "running", "relay": 7})
    record = repo.get_pass(session=session, pass_id=store_recording(session, bare, "otto"))
    rx = short_recording.frames.reception_time_ns
    assert (record.state, record.relay) == ("complete", "imported")
    assert (record.aos_time_ns, record.los_time_ns) == (rx.min(), rx.max())


def test_a_failure_mid_import_leaves_no_rows(
    session: Session, short_recording: PassRecording, monkeypatch: pytest.MonkeyPatch
) -> None:
    before = row_counts(session)

    def refuse(**_: object) -> None:  # the last write, after the frames are in
        raise RuntimeError("disk full")

    monkeypatch.setattr(imports.repo, "add_event", refuse)
    with pytest.raises(RuntimeError, match="disk full"):
        store_recording(session, short_recording, "otto")
    assert row_counts(session) == before


def test_a_row_the_database_refuses_is_reported_and_nothing_is_kept(
    session: Session, short_recording: PassRecording
) -> None:
    before = row_counts(session)
    twice = short_recording.commands[0]
    bad = dataclasses.replace(short_recording, commands=(*short_recording.commands, twice))
    with pytest.raises(InvalidRecording) as caught:
        store_recording(session, bad, "otto")
    assert status_of(caught.value) == 422 and caught.value.code == "recording_not_storable"
    assert row_counts(session) == before


def test_a_recording_whose_pass_name_breaks_the_name_rule_is_refused_saying_why(
    session: Session, short_recording: PassRecording
) -> None:
    """A name read from an archive is shown and quoted to operators as any pass's: one
    that would reorder the text (a right-to-left override) is refused like a typed one."""
    before = row_counts(session)
    bad = dataclasses.replace(short_recording, name="pass \u202e1 tnega")
    with pytest.raises(InvalidRecording) as caught:
        store_recording(session, bad, "otto")
    assert status_of(caught.value) == 422 and caught.value.code == "recording_not_storable"
    assert "U+202E RIGHT-TO-LEFT OVERRIDE" in str(caught.value)
    assert row_counts(session) == before


@pytest.mark.parametrize(
    ("change", "reason"),
    [
        ({"kind": "warp"}, "kind 'warp'"),
        ({"stage": "lost"}, "stage 'lost'"),
        ({"stage_times_ns": {}}, "no queued time"),
    ],
)
def test_commands_the_tables_cannot_take_are_refused_before_writing(
    session: Session, short_recording: PassRecording, change: dict[str, object], reason: str
) -> None:
    command = dataclasses.replace(short_recording.commands[0], **change)  # type: ignore[arg-type]
    bad = dataclasses.replace(short_recording, commands=(command,))
    with pytest.raises(InvalidRecording, match=reason):
        store_recording(session, bad, "otto")
    assert row_counts(session)["passes"] == 0


def test_an_imported_plans_flight_rules_report_is_not_trusted(
    session: Session, short_recording: PassRecording
) -> None:
    """A recording may carry any report (a forged 'passed'): the plan is stored without it,
    so the ground checks it itself before any pass of it may start."""
    forged = {"passed": True, "rows": [], "step_s": 0.25, "n_samples": 1, "n_pairs": 0,
              "n_queries": 0, "clearance": {"t_s": [], "min_m": []}}  # fmt: skip
    carrying = dataclasses.replace(
        short_recording, plan=dataclasses.replace(short_recording.plan, flight_rules=forged)
    )
    pass_id = store_recording(session, carrying, "otto", now_ns=5)
    record = repo.get_pass(session=session, pass_id=pass_id)
    stored = repo.get_plan(session=session, plan_id=record.plan_id)
    assert "flight_rules" not in stored.document
    assert load_recording(session=session, pass_id=pass_id).plan.flight_rules is None
