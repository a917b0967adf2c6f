"""The alarms table through its repository functions, on SQLite and PostgreSQL."""

from __future__ import annotations

import uuid
from typing import Any

import pytest
from sqlalchemy.orm import Session

from server.storage import alarms as repo_alarms
from server.storage import repository as repo
from server.storage.errors import Conflict, InvalidArgument, NotFound
from tests.server.storage.factories import make_plan
from tests.support.alarms import alarm_doc as support_alarm_doc

NOW_NS = 1_790_000_000_000_000_000


def _pass(session: Session) -> str:
    plan = repo.add_plan(session=session, plan=make_plan(), created_at_ns=NOW_NS)
    record = repo.add_pass(
        session=session,
        name="p",
        plan_id=plan.id,
        aos_time_ns=NOW_NS,
        los_time_ns=NOW_NS + 10**12,
        relay="TDRS-W",
        created_at_ns=NOW_NS,
    )
    return record.id


def alarm_doc(pass_id: str | None, **overrides: Any) -> dict[str, Any]:
    return support_alarm_doc(pass_id, now_ns=NOW_NS, **overrides)


def test_an_alarm_round_trips_and_updates(session: Session) -> None:
    pass_id = _pass(session)
    doc = alarm_doc(pass_id)
    assert repo_alarms.save_alarms(session=session, documents=[doc]) == 1
    session.commit()
    session.expunge_all()
    assert (
        repo_alarms.alarm_document(repo_alarms.get_alarm(session=session, alarm_id=doc["id"]))
        == doc
    )
    cleared = {
        **doc,
        "state": "cleared",
        "current_severity": None,
        "severity": "critical",
        "limit": 5.0,
        "worst_value": 6.25,
        "count": 9,
        "cleared_generation_time_ns": 900,
        "cleared_time_ns": NOW_NS + 4,
        "updated_time_ns": NOW_NS + 4,
        "timeline": [*doc["timeline"], {**doc["timeline"][0], "severity": None, "value": 0.1}],
    }
    repo_alarms.save_alarms(session=session, documents=[cleared])
    session.commit()
    session.expunge_all()
    got = repo_alarms.alarm_document(repo_alarms.get_alarm(session=session, alarm_id=doc["id"]))
    assert got == cleared


def test_a_write_of_the_monitor_never_undoes_an_acknowledgement(session: Session) -> None:
    pass_id = _pass(session)
    doc = alarm_doc(pass_id)
    repo_alarms.save_alarms(session=session, documents=[doc])
    acked = repo_alarms.acknowledge(
        session=session, alarm_id=doc["id"], actor="op", time_ns=NOW_NS + 9, comment="seen"
    )
    assert (acked.acknowledged, acked.acknowledged_by, acked.comment) == (True, "op", "seen")
    # a monitor's in-band update written after it, from a state that had not seen it
    stale = {**doc, "count": 3, "updated_time_ns": NOW_NS + 5}
    repo_alarms.save_alarms(session=session, documents=[stale])
    session.commit()
    got = repo_alarms.get_alarm(session=session, alarm_id=doc["id"])
    assert (got.acknowledged, got.acknowledged_by, got.acknowledged_time_ns) == (
        True,
        "op",
        NOW_NS + 9,
    )
    assert got.count == 3 and got.updated_time_ns == NOW_NS + 9  # never moves back


def test_acknowledging_twice_or_an_unknown_alarm_is_refused(session: Session) -> None:
    doc = alarm_doc(_pass(session))
    repo_alarms.save_alarms(session=session, documents=[doc])
    repo_alarms.acknowledge(session=session, alarm_id=doc["id"], actor="op", time_ns=NOW_NS)
    with pytest.raises(Conflict, match="already acknowledged by 'op'"):
        repo_alarms.acknowledge(session=session, alarm_id=doc["id"], actor="op2", time_ns=NOW_NS)
    with pytest.raises(NotFound, match="not found"):
        repo_alarms.acknowledge(
            session=session, alarm_id=str(uuid.uuid4()), actor="op", time_ns=NOW_NS
        )
    with pytest.raises(NotFound, match="not a UUID"):
        repo_alarms.get_alarm(session=session, alarm_id="nope")


def test_listing_is_newest_first_by_pass_and_latching(session: Session) -> None:
    one, two = _pass(session), _pass(session)
    triggered = alarm_doc(one, raised_time_ns=NOW_NS + 1)
    cleared_unacked = alarm_doc(
        one, state="cleared", current_severity=None, raised_time_ns=NOW_NS + 2
    )
    cleared_acked = alarm_doc(
        one,
        state="cleared",
        current_severity=None,
        acknowledged=True,
        acknowledged_by="op",
        raised_time_ns=NOW_NS + 3,
    )
    other = alarm_doc(two, raised_time_ns=NOW_NS + 4)
    vehicle = alarm_doc(
        None, source="vehicle", quantity="vehicle_safing", raised_time_ns=NOW_NS + 5
    )
    docs = [triggered, cleared_unacked, cleared_acked, other, vehicle]
    repo_alarms.save_alarms(session=session, documents=docs)
    session.commit()

    def ids(**kw: Any) -> list[str]:
        return [a.id for a in repo_alarms.list_alarms(session=session, **kw).items]

    assert ids() == [d["id"] for d in reversed(docs)]
    assert ids(pass_id=one) == [cleared_acked["id"], cleared_unacked["id"], triggered["id"]]
    assert ids(pass_id=one, active=True) == [cleared_unacked["id"], triggered["id"]]
    assert ids(pass_id=one, active=False) == [cleared_acked["id"]]
    page = repo_alarms.list_alarms(session=session, active=True, limit=2)
    assert page.count == 4 and len(page.items) == 2
    listed = repo_alarms.listed_alarms(session=session, pass_id=one)
    assert [a.id for a in listed] == [triggered["id"], cleared_unacked["id"]]
    assert [a.id for a in repo_alarms.listed_alarms(session=session, pass_id=None)] == [
        vehicle["id"]
    ]


def test_what_the_table_refuses(session: Session) -> None:
    pass_id = _pass(session)
    with pytest.raises(InvalidArgument, match="severity 'red'"):
        repo_alarms.save_alarms(session=session, documents=[alarm_doc(pass_id, severity="red")])
    with pytest.raises(InvalidArgument, match="not a finite number"):
        repo_alarms.save_alarms(
            session=session, documents=[alarm_doc(pass_id, worst_value=float("nan"))]
        )
    incomplete = alarm_doc(pass_id)
    del incomplete["timeline"]
    with pytest.raises(InvalidArgument, match="lacks"):
        repo_alarms.save_alarms(session=session, documents=[incomplete])


def test_the_tables_severities_are_the_catalogues() -> None:
    from planner.limits import SEVERITIES
    from server.storage.models import ALARM_SEVERITIES

    assert tuple(str(s) for s in SEVERITIES) == ALARM_SEVERITIES
