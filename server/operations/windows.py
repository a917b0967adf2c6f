"""A pass's window, once: the start lead, the window-fit rule and the window enforced.

**The start lead** (:func:`start_lead_s`, onboard s): how long after the start request the
plan's ``t = 0`` falls at most. The larger of ``uplink_start_lead_s`` and the time for the
first command to go up :data:`START_TRANSMISSIONS` times before its last chance (one-way
delay + margin + three first retransmission timeouts, at the link's time scale), plus the
onboard time of :data:`START_SLACK_WALL_S` wall for the start
transaction and one 0.25 s grid step (the epoch is put on the grid at or before it). At
time scale 1 with the default settings: 30 + 1 + 0.25 = 31.25 s. Scheduling uses it at
scale 1, the start gate and the runner at the link's scale, the demo to say where the
epoch will fall.

**The window-fit rule** (:func:`check_fit`): a plan needs its duration and the start lead;
where a window holds less, the conflict ``plan_exceeds_window`` (409), its detail the time
needed and the time available and the window's AOS and LOS. Scheduling applies it to the
whole usable window (a hand window's AOS to LOS; a named one's net time), the start gate to
what is left of it at the ground's time.

**The window enforced** (:func:`start_refusal`): a pass does not start before its usable
window opens nor after it closed (409 ``outside_window``, the window and the ground's time
named), nor so late that its last command's tag would fall after the usable end (a named
window's LOS less the mission's LOS margin; a hand window's LOS): ``plan_exceeds_window``.

**Whose time** (docs/missions.md "The window is enforced"): a window is in UTC, and the
windows' time line is the ground's clock (:class:`WindowTime`, ``window_clock = "ground"``,
the injected clock: tests move it). A vehicle flying at time scale ``k`` flies ``k``
onboard s per ground s, so the plan's onboard span takes ``1/k`` of it on the ground's
clock. A simulation that flies a mission's day (the campaign demo: a vehicle whose onboard
clock reads the mission's UTC, ``hikoboshi spacecraft --mission``) judges its windows on
that clock (``window_clock = "vehicle"``: onboard now as the ground reads it; spans 1:1).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal

from server.schemas import iso_from_ns, ns_from_datetime
from server.services.errors import ConflictError
from server.services.uplink import RttEstimator
from server.settings import Settings
from telemetry.uplink import GRID_NS

if TYPE_CHECKING:  # what the start path hands in: the CLI's campaign imports this module
    from mission import Window
    from server.services.link import GroundLink
    from server.storage.models import PassRecord

__all__ = [
    "OUTSIDE_WINDOW",
    "PLAN_EXCEEDS_WINDOW",
    "START_SLACK_WALL_S",
    "START_TRANSMISSIONS",
    "PassWindow",
    "Refusal",
    "WindowTime",
    "check_fit",
    "start_lead_s",
    "start_refusal",
    "window_time",
]

#: A pass starts late enough for its first command to go up this many times (the first
#: timeout, before any round-trip sample) before its last chance.
START_TRANSMISSIONS = 3
#: Wall s allowed for the start transaction itself, within the start lead (its first use
#: of a fresh PostgreSQL connection can take a few hundred ms: at 20x that is seconds
#: onboard).
START_SLACK_WALL_S = 1.0
#: The one code of a plan that does not fit (what is left of) its window.
PLAN_EXCEEDS_WINDOW = "plan_exceeds_window"
#: A start before the window opened or after it closed.
OUTSIDE_WINDOW = "outside_window"


def start_lead_s(settings: Settings, time_scale: float = 1.0) -> float:
    """Onboard s from a start request to its plan's ``t = 0``, at most (module doc)."""
    delay_s = settings.link_one_way_delay_s
    first_rto_s = RttEstimator(2 * delay_s / time_scale).rto_s
    uplink_s = delay_s + settings.uplink_margin_s + START_TRANSMISSIONS * first_rto_s * time_scale
    slack_s = START_SLACK_WALL_S * time_scale + GRID_NS / 1e9
    return max(settings.uplink_start_lead_s, uplink_s) + slack_s


def _utc(time_ns: int) -> str:
    return iso_from_ns(time_ns).isoformat().replace("+00:00", "Z")


@dataclass(frozen=True)
class PassWindow:
    """A pass's window: the part a pass may use (``start_ns`` to ``end_ns``: a hand
    window's AOS to LOS, a named one's net time) and, for a named one, the window itself."""

    start_ns: int
    end_ns: int
    relay: str
    aos_ns: int
    los_ns: int
    mission: str | None = None
    aos_margin_s: float = 0.0
    los_margin_s: float = 0.0

    @classmethod
    def of_record(cls, record: PassRecord) -> PassWindow:
        doc = record.window_detail
        if record.window_mission is None or doc is None:
            return cls(
                record.aos_time_ns,
                record.los_time_ns,
                record.relay,
                record.aos_time_ns,
                record.los_time_ns,
            )
        return cls(
            record.aos_time_ns,
            record.los_time_ns,
            record.relay,
            int(doc["aos_time_ns"]),
            int(doc["los_time_ns"]),
            record.window_mission,
            float(doc["aos_margin_s"]),
            float(doc["los_margin_s"]),
        )

    @classmethod
    def of_mission(cls, window: Window, mission: str = "") -> PassWindow:
        """A mission's computed window (of the mission named, if given): a pass uses its net
        time."""
        return cls(
            ns_from_datetime(window.net_start_utc),
            ns_from_datetime(window.net_end_utc),
            window.relay,
            ns_from_datetime(window.aos_utc),
            ns_from_datetime(window.los_utc),
            mission,
            window.aos_margin_s,
            window.los_margin_s,
        )

    @property
    def usable_s(self) -> float:
        return (self.end_ns - self.start_ns) / 1e9

    def describe(self) -> str:
        """``TDRS-West's window of mission ets7-1999 (AOS ..., LOS ...; net ... to ...)``."""
        span = f"AOS {_utc(self.aos_ns)}, LOS {_utc(self.los_ns)}"
        if self.mission is None:
            return f"{self.relay}'s window ({span})"
        of = f" of mission {self.mission}" if self.mission else ""
        return (
            f"{self.relay}'s window{of} ({span}; net time "
            f"{_utc(self.start_ns)} to {_utc(self.end_ns)}, {self.aos_margin_s:g} s after AOS "
            f"and {self.los_margin_s:g} s before LOS)"
        )

    def detail(self) -> dict[str, Any]:
        return {
            "relay": self.relay,
            "mission": self.mission,
            "aos_time": _utc(self.aos_ns),
            "los_time": _utc(self.los_ns),
            "net_start_time": _utc(self.start_ns),
            "net_end_time": _utc(self.end_ns),
        }


@dataclass(frozen=True)
class WindowTime:
    """Now on the windows' time line, and the onboard s the vehicle flies per s of it."""

    now_ns: int
    scale: float = 1.0
    #: whose clock: "ground" (the ground's) or "vehicle" (onboard, a simulated mission's UTC)
    clock: Literal["ground", "vehicle"] = "ground"

    def describe(self) -> str:
        return f"the {self.clock}'s time is {_utc(self.now_ns)}"


def window_time(settings: Settings, ground_now_ns: int, link: GroundLink) -> WindowTime | None:
    """Now on the windows' time line (module doc): the ground's clock (``ground_now_ns``,
    read off the injected clock) at the link's time scale (1 without a link), or with
    ``window_clock = "vehicle"`` the onboard clock; None when that needs a link and there
    is none (the runner then refuses the start ``link_down``)."""
    if settings.window_clock == "vehicle":
        if not link.connected:
            return None
        return WindowTime(link.onboard_now_ns(), 1.0, "vehicle")
    return WindowTime(ground_now_ns, link.time_scale if link.connected else 1.0)


@dataclass(frozen=True)
class Refusal:
    """Why a window refuses a pass: the conflict's code, message and detail."""

    code: str
    message: str
    detail: dict[str, Any]

    def error(self) -> ConflictError:
        return ConflictError(self.code, self.message, self.detail)


def check_fit(
    window: PassWindow,
    *,
    plan_id: str,
    plan_s: float,
    lead_s: float,
    available_s: float | None = None,
    at: WindowTime | None = None,
) -> Refusal | None:
    """The window-fit rule: the plan (``plan_s``) and the start lead (``lead_s``, onboard
    s) against the ``available_s`` s of ``window`` left (from ``at``'s now; None: all of its
    usable time); a refusal ``plan_exceeds_window`` where they do not fit, else None."""
    if available_s is None:
        available_s = window.usable_s
    scale = 1.0 if at is None else at.scale
    needed_s = (plan_s + lead_s) / scale
    if needed_s <= available_s:
        return None
    scaled = "" if scale == 1.0 else f" onboard, {needed_s:.3f} s at time scale {scale:g}"
    if at is None:
        left = f"holds {available_s:.3f} s"
    else:
        left = f"has {max(available_s, 0.0):.3f} s left ({at.describe()})"
    end = "LOS" if window.mission is None else "LOS less the margin"
    message = (
        f"plan {plan_id} needs {needed_s * scale:.3f} s ({plan_s:.3f} s and the {lead_s:.3f} s "
        f"start lead){scaled} before the window's {end}; {window.describe()} {left}"
    )
    detail = {"needed_s": needed_s, "available_s": available_s, **window.detail()}
    if at is None:
        detail["net_s"] = available_s
    else:
        detail["ground_time" if at.clock == "ground" else "vehicle_time"] = _utc(at.now_ns)
        detail["latest_start_time"] = _utc(window.end_ns - round(needed_s * 1e9))
    return Refusal(PLAN_EXCEEDS_WINDOW, message, detail)


def start_refusal(
    record: PassRecord, *, plan_s: float, lead_s: float, at: WindowTime
) -> Refusal | None:
    """Why pass ``record`` may not start at ``at`` (module doc), or None."""
    window = PassWindow.of_record(record)
    outside = None
    if at.now_ns < window.start_ns:
        outside = "has not opened yet"
    elif at.now_ns >= window.end_ns:
        outside = "has closed"
    if outside is not None:
        usable = "window" if window.mission is None else "window's net time"
        message = (
            f"pass {record.name!r} will not start: its {usable} {outside}: "
            f"{window.describe()}; {at.describe()}"
        )
        when = "ground_time" if at.clock == "ground" else "vehicle_time"
        return Refusal(OUTSIDE_WINDOW, message, {**window.detail(), when: _utc(at.now_ns)})
    late = check_fit(
        window,
        plan_id=record.plan_id,
        plan_s=plan_s,
        lead_s=lead_s,
        available_s=(window.end_ns - at.now_ns) / 1e9,
        at=at,
    )
    if late is None:
        return None
    message = f"pass {record.name!r} will not start: its last command would fall late: "
    return Refusal(late.code, message + late.message, late.detail)
