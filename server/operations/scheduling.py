"""Scheduling a pass: a stored plan in a window, fitted to it once.

A window is given by hand (``aos_time``, ``los_time``: the pass may use all of it) or named
(mission, relay, AOS time: :mod:`server.services.missions` computes it; the pass runs in its
net time, the window less the mission's margins, and the window is stored with the pass).
Either way the window must hold the plan and the start lead before its first command
(:func:`server.operations.windows.start_lead_s` at time scale 1): else the conflict
``plan_exceeds_window`` (:func:`server.operations.windows.check_fit`, docs/missions.md).
Where the pass may then start is the start gate's (:mod:`server.operations.start_gate`).
"""

from __future__ import annotations

from sqlalchemy.orm import Session

from server.operations.windows import PassWindow, check_fit, start_lead_s
from server.schemas import EARLIEST, LATEST, ns_from_datetime
from server.schemas.passes import PassCreate, PassCreateFromWindow, PassPublic
from server.services.errors import InvalidRequestError
from server.services.missions import window_for_pass
from server.services.passes import add_scheduled, public
from server.settings import Settings
from server.storage import repository as repo

__all__ = ["schedule_pass"]


def schedule_pass(
    *,
    session: Session,
    settings: Settings,
    request: PassCreate | PassCreateFromWindow,
    actor: str,
    now_ns: int,
) -> PassPublic:
    """Store a ``scheduled`` pass and the audit event ``pass_scheduled`` in one transaction.

    Storage's ``NotFound`` for an unknown plan; an invalid request for a hand window that is
    reversed or outside 1970..2200; for a named window, the refusals of
    :mod:`server.services.missions`; the conflict ``plan_exceeds_window`` for a window that
    does not hold the plan and the start lead.
    """
    fields: dict[str, object]
    if isinstance(request, PassCreateFromWindow):
        window, document = window_for_pass(settings, request.window)
        span = PassWindow.of_mission(window, document["mission"])
        fields = {"window_mission": document["mission"], "window_detail": document}
    else:
        aos_ns, los_ns = _hand_window(request)
        span = PassWindow(aos_ns, los_ns, request.relay, aos_ns, los_ns)
        fields = {}
    try:
        plan = repo.get_plan(session=session, plan_id=request.plan_id)
        refusal = check_fit(
            span,
            plan_id=plan.id,
            plan_s=plan.duration_s,
            lead_s=start_lead_s(settings),
        )
        if refusal is not None:
            raise refusal.error()
        record = add_scheduled(
            session,
            actor,
            now_ns,
            name=request.name,
            plan_id=plan.id,
            aos_time_ns=span.start_ns,
            los_time_ns=span.end_ns,
            relay=span.relay,
            **fields,
        )
    except BaseException:
        session.rollback()
        raise
    return public(record)


def _hand_window(request: PassCreate) -> tuple[int, int]:
    """The hand window's AOS and LOS (ns); an invalid request when outside 1970..2200 or
    reversed."""
    for label, value in (("aos_time", request.aos_time), ("los_time", request.los_time)):
        if not EARLIEST <= value < LATEST:
            raise InvalidRequestError(
                "time_out_of_range", f"{label} {value.isoformat()} is outside 1970..2200"
            )
    aos_ns = ns_from_datetime(request.aos_time)
    los_ns = ns_from_datetime(request.los_time)
    if los_ns <= aos_ns:
        raise InvalidRequestError(
            "window_reversed",
            f"los_time {request.los_time.isoformat()} is not after "
            f"aos_time {request.aos_time.isoformat()}",
        )
    return aos_ns, los_ns
