"""Round trips of every table through the repository, and its errors."""

from __future__ import annotations

import json

import pytest
from sqlalchemy import Engine, func, select
from sqlalchemy.orm import Session

from planner.plan import Plan
from server.storage import repository as repo
from server.storage.db import session_factory
from server.storage.errors import Conflict, InvalidArgument, NotFound, StorageError
from server.storage.models import CommandRecord, PassRecord
from tests.server.storage.factories import T0_NS, make_commands, make_plan

NOW_NS = 1_790_000_000_000_000_000  # a ground time, ns since the Unix epoch


def _pass(session: Session, **overrides: object) -> PassRecord:
    plan = repo.add_plan(session=session, plan=make_plan(), created_at_ns=NOW_NS)
    args: dict[str, object] = {
        "name": "pass 1",
        "plan_id": plan.id,
        "aos_time_ns": NOW_NS + 10**9,
        "los_time_ns": NOW_NS + 1200 * 10**9,
        "relay": "TDRS-W",
        "created_at_ns": NOW_NS,
    }
    args.update(overrides)
    return repo.add_pass(session=session, **args)  # type: ignore[arg-type]


def test_plan_round_trip(engine: Engine) -> None:
    plan = make_plan(n_commands=9)
    with session_factory(engine)() as session:
        stored = repo.add_plan(session=session, plan=plan, created_at_ns=NOW_NS)
        session.commit()
    with session_factory(engine)() as session:
        got = repo.get_plan(session=session, plan_id=stored.id)
        assert got.experiment == "ptp"
        assert got.parameters == {"out_speed_mps": 0.01, "label": "A->B"}
        assert got.duration_s == 2.0
        assert got.n_commands == 9 + 1  # joint commands and the ACS command
        assert got.created_at_ns == NOW_NS
        assert got.document == plan.to_json()
        again = Plan.from_json(got.document)
        assert json.loads(again.to_json()) == json.loads(plan.to_json())


def test_list_plans_pages_newest_first_without_documents(session: Session) -> None:
    ids = [
        repo.add_plan(session=session, plan=make_plan(experiment=e), created_at_ns=NOW_NS + i).id
        for i, e in enumerate(["ptp", "gjm", "ptp"])
    ]
    session.commit()
    session.expunge_all()
    page = repo.list_plans(session=session, limit=2)
    assert page.count == 3
    assert [p.id for p in page.items] == [ids[2], ids[1]]
    with pytest.raises(Exception, match="document"):
        _ = page.items[0].document  # deferred and not loaded: a listing stays small
    only_ptp = repo.list_plans(session=session, experiment="ptp")
    assert (only_ptp.count, [p.id for p in only_ptp.items]) == (2, [ids[2], ids[0]])


def test_pass_round_trip(engine: Engine) -> None:
    with session_factory(engine)() as session:
        stored = _pass(session)
        session.commit()
    with session_factory(engine)() as session:
        got = repo.get_pass(session=session, pass_id=stored.id)
        assert (got.name, got.relay, got.state, got.version) == ("pass 1", "TDRS-W", "scheduled", 1)
        assert (got.aos_time_ns, got.los_time_ns) == (NOW_NS + 10**9, NOW_NS + 1200 * 10**9)
        assert got.plan_id == stored.plan_id
        assert got.epoch_ns is None and got.state_reason is None
        assert got.created_at_ns == got.updated_at_ns == NOW_NS
        # ids are canonical UUID strings whatever the case they are asked in
        assert repo.get_pass(session=session, pass_id=stored.id.upper()).id == stored.id


def test_list_passes_by_aos_and_state(session: Session) -> None:
    late = _pass(session, name="late", aos_time_ns=NOW_NS + 5 * 10**9)
    early = _pass(session, name="early", aos_time_ns=NOW_NS + 2 * 10**9)
    repo.update_pass_state(
        session=session, pass_id=late.id, expected_version=1, state="aos", updated_at_ns=NOW_NS
    )
    page = repo.list_passes(session=session)
    assert [p.name for p in page.items] == ["early", "late"] and page.count == 2
    scheduled = repo.list_passes(session=session, states=["scheduled"])
    assert [p.id for p in scheduled.items] == [early.id]
    with pytest.raises(InvalidArgument, match="'flying'"):
        repo.list_passes(session=session, states=["flying"])


def test_pass_state_update_bumps_the_version(engine: Engine) -> None:
    with session_factory(engine)() as session:
        p = _pass(session)
        updated = repo.update_pass_state(
            session=session,
            pass_id=p.id,
            expected_version=1,
            state="running",
            reason="operator go",
            updated_at_ns=NOW_NS + 7,
            epoch_ns=T0_NS,
        )
        assert updated.version == 2
        session.commit()
    with session_factory(engine)() as session:
        got = repo.get_pass(session=session, pass_id=p.id)
        assert (got.state, got.state_reason, got.epoch_ns, got.version) == (
            "running",
            "operator go",
            T0_NS,
            2,
        )
        assert got.updated_at_ns == NOW_NS + 7


def test_optimistic_lock_refuses_a_stale_version(engine: Engine) -> None:
    factory = session_factory(engine)
    with factory() as session:
        pass_id = _pass(session).id
        session.commit()
    # Two operators read version 1 ...
    with factory() as first, factory() as second:
        seen_by_first = repo.get_pass(session=first, pass_id=pass_id)
        first.commit()
        seen_by_second = repo.get_pass(session=second, pass_id=pass_id)
        second.commit()
        assert seen_by_first.version == seen_by_second.version == 1
        # ... the second writes first ...
        repo.update_pass_state(
            session=second, pass_id=pass_id, expected_version=1, state="aos", updated_at_ns=1
        )
        second.commit()
        # ... and the first, still holding version 1 in its session, is refused.
        with pytest.raises(Conflict, match="at version 2, not the expected 1"):
            repo.update_pass_state(
                session=first,
                pass_id=pass_id,
                expected_version=1,
                state="aborted",
                updated_at_ns=2,
            )
        first.rollback()
        # Asked with the current version, it goes through even from the stale session.
        repo.update_pass_state(
            session=first, pass_id=pass_id, expected_version=2, state="aborted", updated_at_ns=3
        )
        first.commit()
    with factory() as session:
        got = repo.get_pass(session=session, pass_id=pass_id)
        assert (got.state, got.version) == ("aborted", 3)


def test_pass_errors(session: Session) -> None:
    p = _pass(session)
    with pytest.raises(NotFound):
        repo.get_pass(session=session, pass_id="00000000-0000-0000-0000-000000000000")
    with pytest.raises(NotFound, match="not a UUID"):
        repo.get_pass(session=session, pass_id="'; DROP TABLE passes; --")
    with pytest.raises(NotFound, match="plan"):
        _pass(session, plan_id="00000000-0000-0000-0000-000000000000")
    with pytest.raises(InvalidArgument, match="'flying'"):
        repo.update_pass_state(
            session=session, pass_id=p.id, expected_version=1, state="flying", updated_at_ns=1
        )
    with pytest.raises(InvalidArgument, match="before its AOS"):
        _pass(session, aos_time_ns=10, los_time_ns=5)
    with pytest.raises(Conflict):
        _pass(session, pass_id=p.id)
    assert issubclass(Conflict, StorageError) and issubclass(NotFound, StorageError)


def test_commands_round_trip_with_payloads(engine: Engine) -> None:
    commands = make_commands(5)
    with session_factory(engine)() as session:
        pass_id = _pass(session).id
        assert (
            repo.add_commands(
                session=session, pass_id=pass_id, commands=commands, queued_at_ns=NOW_NS
            )
            == 5
        )
        session.commit()
    with session_factory(engine)() as session:
        stored = repo.list_commands(session=session, pass_id=pass_id)
        assert [c.seq for c in stored] == [0, 1, 2, 3, 4]
        acs, joint = stored[0], stored[1]
        assert (acs.kind, acs.execute_time_ns, acs.stage) == ("acs", T0_NS, "queued")
        assert acs.payload == {
            "mode": "free_drift",
            "target_quat_orbit_from_base_xyzw": [0.0, 0.0, 0.1, 0.995],
            "feedforward": True,
        }
        assert joint.kind == "joints" and joint.execute_time_ns == T0_NS + 250_000_000
        assert joint.payload == {"joints_rad": [0.01, -0.01, 0.0, 0.5, 0.0, 0.25]}
        assert all(c.queued_at_ns == NOW_NS for c in stored)
        assert all(
            getattr(c, f"{s}_at_ns") is None
            for c in stored
            for s in ("released", "sent", "received", "executed", "rejected", "expired")
        )


def test_command_stages_record_their_times(session: Session) -> None:
    pass_id = _pass(session).id
    repo.add_commands(
        session=session, pass_id=pass_id, commands=make_commands(4), queued_at_ns=NOW_NS
    )
    for stage, t in (("released", 1), ("sent", 2), ("received", 3), ("executed", 4)):
        repo.update_command_stage(session=session, pass_id=pass_id, seq=1, stage=stage, time_ns=t)
    repo.update_command_stage(
        session=session,
        pass_id=pass_id,
        seq=2,
        stage="rejected",
        time_ns=9,
        reject_reason="out_of_limits",
    )
    repo.update_command_stage(session=session, pass_id=pass_id, seq=3, stage="expired", time_ns=8)
    session.commit()
    session.expunge_all()
    one = repo.get_command(session=session, pass_id=pass_id, seq=1)
    assert one.stage == "executed"
    assert (one.released_at_ns, one.sent_at_ns, one.received_at_ns, one.executed_at_ns) == (
        1,
        2,
        3,
        4,
    )
    two = repo.get_command(session=session, pass_id=pass_id, seq=2)
    assert (two.stage, two.reject_reason, two.rejected_at_ns) == ("rejected", "out_of_limits", 9)
    assert repo.get_command(session=session, pass_id=pass_id, seq=3).expired_at_ns == 8
    with pytest.raises(InvalidArgument, match="'lost'"):
        repo.update_command_stage(session=session, pass_id=pass_id, seq=1, stage="lost", time_ns=1)
    with pytest.raises(NotFound, match="command 99"):
        repo.update_command_stage(session=session, pass_id=pass_id, seq=99, stage="sent", time_ns=1)


def test_list_commands_filters_by_stage_and_tag_range(session: Session) -> None:
    pass_id = _pass(session).id
    repo.add_commands(
        session=session, pass_id=pass_id, commands=make_commands(8), queued_at_ns=NOW_NS
    )
    for seq in (0, 1, 2):
        repo.update_command_stage(
            session=session, pass_id=pass_id, seq=seq, stage="sent", time_ns=5
        )
    queued = repo.list_commands(session=session, pass_id=pass_id, stages=["queued"])
    assert [c.seq for c in queued] == [3, 4, 5, 6, 7]
    window = repo.list_commands(
        session=session,
        pass_id=pass_id,
        execute_from_ns=T0_NS + 2 * 250_000_000,
        execute_to_ns=T0_NS + 5 * 250_000_000,
    )
    assert [c.seq for c in window] == [2, 3, 4]  # half-open: the tag at the end is out
    both = repo.list_commands(
        session=session,
        pass_id=pass_id,
        stages=["queued", "sent"],
        execute_from_ns=T0_NS + 250_000_000,
        limit=3,
    )
    assert [c.seq for c in both] == [1, 2, 3]


def test_duplicate_command_seq_is_a_conflict_and_nothing_of_the_batch_stays(
    engine: Engine,
) -> None:
    factory = session_factory(engine)
    with factory() as session:
        pass_id = _pass(session).id
        repo.add_commands(
            session=session, pass_id=pass_id, commands=make_commands(3), queued_at_ns=NOW_NS
        )
        session.commit()
    with factory() as session:
        with pytest.raises(Conflict):
            repo.add_commands(
                session=session,
                pass_id=pass_id,
                commands=make_commands(4, first_seq=100) + make_commands(1, first_seq=2),
                queued_at_ns=NOW_NS,
            )
        session.rollback()
        assert session.scalar(select(func.count()).select_from(CommandRecord)) == 3
    with factory() as session, pytest.raises(NotFound):
        repo.add_commands(
            session=session,
            pass_id="00000000-0000-0000-0000-000000000000",
            commands=make_commands(1),
            queued_at_ns=NOW_NS,
        )


def test_events_round_trip_and_filters(session: Session) -> None:
    pass_id = _pass(session).id
    first = repo.add_event(session=session, time_ns=30, kind="login", actor="alice")
    repo.add_event(
        session=session,
        time_ns=10,
        kind="pass.state",
        actor="bob",
        pass_id=pass_id,
        detail={"from": "scheduled", "to": "aos", "version": 2},
    )
    repo.add_event(
        session=session,
        time_ns=20,
        kind="command.sent",
        actor="server",
        pass_id=pass_id,
        detail={"seqs": [0, 1, 2]},
    )
    session.commit()
    session.expunge_all()
    assert first.id is not None
    everything = repo.list_events(session=session)
    assert [e.time_ns for e in everything.items] == [10, 20, 30] and everything.count == 3
    state = everything.items[0]
    assert (state.kind, state.actor, state.pass_id) == ("pass.state", "bob", pass_id)
    assert state.detail == {"from": "scheduled", "to": "aos", "version": 2}
    assert everything.items[2].detail == {} and everything.items[2].pass_id is None
    of_pass = repo.list_events(session=session, pass_id=pass_id)
    assert [e.kind for e in of_pass.items] == ["pass.state", "command.sent"]
    window = repo.list_events(session=session, t0_ns=15, t1_ns=31, kinds=["login"])
    assert [e.id for e in window.items] == [first.id]
    paged = repo.list_events(session=session, offset=1, limit=1)
    assert [e.time_ns for e in paged.items] == [20] and paged.count == 3
    with pytest.raises(NotFound):
        repo.add_event(
            session=session,
            time_ns=1,
            kind="x",
            actor="y",
            pass_id="00000000-0000-0000-0000-000000000000",
        )


def test_analysis_round_trip_newest_is_current(session: Session) -> None:
    pass_id = _pass(session).id
    repo.add_analysis(
        session=session,
        pass_id=pass_id,
        kind="tracking",
        result={"rms_deg": 0.5},
        created_at_ns=1,
    )
    newer = repo.add_analysis(
        session=session,
        pass_id=pass_id,
        kind="tracking",
        result={"rms_deg": 0.25, "per_joint": [0.1, 0.2]},
        created_at_ns=2,
    )
    repo.add_analysis(session=session, pass_id=pass_id, kind="attitude", result={}, created_at_ns=3)
    session.commit()
    session.expunge_all()
    got = repo.get_analysis(session=session, pass_id=pass_id, kind="tracking")
    assert got.id == newer.id and got.result == {"rms_deg": 0.25, "per_joint": [0.1, 0.2]}
    assert [a.kind for a in repo.list_analyses(session=session, pass_id=pass_id)] == [
        "tracking",
        "tracking",
        "attitude",
    ]
    with pytest.raises(NotFound, match="'energy'"):
        repo.get_analysis(session=session, pass_id=pass_id, kind="energy")


def test_json_refuses_nan_on_every_backend(session: Session) -> None:
    pass_id = _pass(session).id
    with pytest.raises(InvalidArgument, match="not JSON compliant"):
        repo.add_analysis(
            session=session, pass_id=pass_id, kind="x", result={"v": float("nan")}, created_at_ns=1
        )
