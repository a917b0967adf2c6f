"""Contact windows: when the vehicle sees each relay, from ``skyfield`` and ``sgp4``
(docs/missions.md, SPEC section 8).

    compute_windows(mission, start_utc, hours, on_progress=None) -> list[Window]

The vehicle is propagated with SGP4 (skyfield's ``EarthSatellite`` over the mission's
``sgp4`` record) and placed in the Earth-fixed frame (ITRS); the relays are geostationary,
fixed there. A relay is visible when the segment from the vehicle to the relay stays
``earth_radius_km + grazing_height_km`` from the Earth's centre. Visibility is scanned on a
60 s grid and each change is bracketed to 1 ms by skyfield's ``find_discrete``; a window or
gap shorter than the grid step can be missed (LEO-GEO gaps last tens of minutes).

The Earth-fixed frame takes the IAU 2000B nutation, as skyfield's almanac searches do
(within a milliarcsecond of 2000A: 0.2 m at the relay's distance).

The windows listed are those whose acquisition falls in ``[start, start + hours)``; the
scan runs at least two orbits either side so that each listed window is whole, over whole
2 h chunks counted from the elements' epoch, so that a window's times do not depend on
the span that found it. Nothing is
downloaded: time scales are skyfield's builtin tables (``load.timescale(builtin=True)``)
and no planetary ephemeris is needed.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from functools import cache
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mission.errors import InvalidSpan
from mission.file import Mission, Relay

__all__ = [
    "LIGHT_SPEED_KMPS",
    "MAX_EPOCH_DISTANCE_DAYS",
    "MAX_HOURS",
    "SCAN_STEP_S",
    "Window",
    "compute_windows",
    "format_utc",
    "light_times",
    "parse_utc",
    "segment_clearance_km",
]

LIGHT_SPEED_KMPS = 299792.458
#: The coarse scan's step: visibility is sampled this often before bracketing.
SCAN_STEP_S = 60.0
#: How finely each acquisition and loss is bracketed (skyfield's find_discrete epsilon).
EPSILON_S = 0.001
#: Ranges over a window are sampled at least this often (the minimum is off by < 0.1 km).
RANGE_STEP_S = 10.0
#: The longest span one call computes (31 days).
MAX_HOURS = 744.0
#: Mean elements are not propagated further than this from their epoch: SGP4's error grows
#: by kilometres a day, and our own elements carry no drag (docs/missions.md).
MAX_EPOCH_DISTANCE_DAYS = 60.0
#: The scan is cut in pieces this long, counted from the elements' epoch (a caller shows
#: progress by them).
_CHUNK_S = 2 * 3600.0

ProgressFn = Callable[[float, float], None]


@dataclass(frozen=True)
class Window:
    """One contact window: the vehicle sees ``relay`` from ``aos_utc`` to ``los_utc``."""

    relay: str
    aos_utc: datetime
    los_utc: datetime
    min_range_km: float
    max_range_km: float
    light_time_min_s: float  # one way, vehicle -> relay -> ground terminal
    light_time_max_s: float
    aos_margin_s: float
    los_margin_s: float

    @property
    def duration_s(self) -> float:
        return (self.los_utc - self.aos_utc).total_seconds()

    @property
    def net_s(self) -> float:
        """The time a pass may use: the window less its margins (never negative)."""
        return max(0.0, self.duration_s - self.aos_margin_s - self.los_margin_s)

    @property
    def net_start_utc(self) -> datetime:
        return self.aos_utc + timedelta(seconds=self.aos_margin_s)

    @property
    def net_end_utc(self) -> datetime:
        return self.los_utc - timedelta(seconds=self.los_margin_s)

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> Window:
        """The window :meth:`to_dict` wrote (``hikoboshi windows --json``'s items); the
        margins from its net start and end. InvalidSpan naming what is wrong."""
        try:
            aos, los = parse_utc(str(doc["aos_utc"])), parse_utc(str(doc["los_utc"]))
            net_start = parse_utc(str(doc.get("net_start_utc", doc["aos_utc"])))
            net_end = parse_utc(str(doc.get("net_end_utc", doc["los_utc"])))
            window = cls(
                relay=str(doc["relay"]),
                aos_utc=aos,
                los_utc=los,
                min_range_km=float(doc.get("min_range_km", 0.0)),
                max_range_km=float(doc.get("max_range_km", 0.0)),
                light_time_min_s=float(doc.get("light_time_min_s", 0.0)),
                light_time_max_s=float(doc.get("light_time_max_s", 0.0)),
                aos_margin_s=(net_start - aos).total_seconds(),
                los_margin_s=(los - net_end).total_seconds(),
            )
        except KeyError as exc:
            raise InvalidSpan(f"a window has no {exc.args[0]}") from None
        except (TypeError, ValueError) as exc:
            raise InvalidSpan(f"a window is not readable: {exc}") from None
        if not aos < los:
            raise InvalidSpan(f"window {doc['aos_utc']} .. {doc['los_utc']}: LOS not after AOS")
        return window

    def to_dict(self) -> dict[str, Any]:
        return {
            "relay": self.relay,
            "aos_utc": format_utc(self.aos_utc),
            "los_utc": format_utc(self.los_utc),
            "duration_s": round(self.duration_s, 3),
            "net_start_utc": format_utc(self.net_start_utc),
            "net_end_utc": format_utc(self.net_end_utc),
            "net_s": round(self.net_s, 3),
            "min_range_km": round(self.min_range_km, 3),
            "max_range_km": round(self.max_range_km, 3),
            "light_time_min_s": round(self.light_time_min_s, 6),
            "light_time_max_s": round(self.light_time_max_s, 6),
        }


def format_utc(moment: datetime) -> str:
    """``YYYY-MM-DDTHH:MM:SS.mmmZ``."""
    return moment.astimezone(UTC).strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z"


def parse_utc(text: str) -> datetime:
    """An ISO 8601 time with its UTC offset (``Z`` or ``+hh:mm``), as UTC; InvalidSpan if
    it is not one."""
    try:
        moment = datetime.fromisoformat(text.strip())
    except ValueError:
        raise InvalidSpan(f"start {text!r} is not an ISO 8601 time") from None
    if moment.tzinfo is None:
        raise InvalidSpan(f"start {text!r} has no UTC offset (write e.g. 1999-09-30T00:00:00Z)")
    try:
        return moment.astimezone(UTC)
    except OverflowError:
        raise InvalidSpan(f"start {text!r} is outside the years 1 to 9999 in UTC") from None


def segment_clearance_km(
    vehicle_km: NDArray[np.float64], relay_km: NDArray[np.float64]
) -> NDArray[np.float64]:
    """The smallest distance from the Earth's centre of each segment vehicle -> relay
    (``vehicle_km`` shape (n, 3), ``relay_km`` shape (3,); one frame, any frame)."""
    d = relay_km[None, :] - vehicle_km
    s = -np.einsum("ij,ij->i", vehicle_km, d) / np.einsum("ij,ij->i", d, d)
    s = np.clip(s, 0.0, 1.0)
    closest = vehicle_km + s[:, None] * d
    return np.asarray(np.linalg.norm(closest, axis=1), dtype=np.float64)


@cache
def _timescale() -> Any:
    from skyfield.api import load

    return load.timescale(builtin=True)


def compute_windows(
    mission: Mission,
    start_utc: datetime,
    hours: float,
    on_progress: ProgressFn | None = None,
) -> list[Window]:
    """Every window whose acquisition falls in ``[start_utc, start_utc + hours)``, by
    acquisition time; ``on_progress(done_s, total_s)`` as the scan goes."""
    from skyfield.api import EarthSatellite
    from skyfield.framelib import itrs
    from skyfield.nutationlib import iau2000b_radians
    from skyfield.searchlib import find_discrete

    if start_utc.tzinfo is None:
        raise InvalidSpan("start has no UTC offset")
    if not (math.isfinite(hours) and 0.0 < hours <= MAX_HOURS):
        raise InvalidSpan(f"hours {hours:g} is outside (0, {MAX_HOURS:g}]")
    epoch = mission.orbit.epoch_utc
    # Aware datetimes subtract without overflow whatever their offsets; the span's end is
    # made only once its start is known to be near the epoch (years 1 and 9999 are safe).
    start_days = (start_utc - epoch).total_seconds() / 86400.0
    end_days = start_days + hours / 24.0
    for days in (start_days, end_days):
        if abs(days) > MAX_EPOCH_DISTANCE_DAYS:
            raise InvalidSpan(
                f"{start_utc.isoformat()} + {hours:g} h reaches {abs(days):.1f} days from the "
                f"elements' epoch {format_utc(epoch)}, over the {MAX_EPOCH_DISTANCE_DAYS:g} "
                "day limit"
            )
    start_utc = start_utc.astimezone(UTC)
    end_utc = start_utc + timedelta(hours=hours)

    ts = _timescale()
    satrec = mission.orbit.satrec()
    sat = EarthSatellite.from_satrec(satrec, ts)
    period_s = 2.0 * math.pi / satrec.no_kozai * 60.0
    # The scan runs over whole chunks counted from the elements' epoch, so that a window is
    # bracketed on the same samples whatever span asked for it (GET /api/windows and a pass
    # naming the window agree to the nanosecond).
    first = math.floor(((start_utc - epoch).total_seconds() - 2.0 * period_s) / _CHUNK_S)
    last = math.ceil(((end_utc - epoch).total_seconds() + 2.0 * period_s) / _CHUNK_S)
    scan_from = epoch + timedelta(seconds=first * _CHUNK_S)
    scan_to = epoch + timedelta(seconds=last * _CHUNK_S)
    clearance_km = mission.visibility.clearance_radius_km
    relays_km = [np.array(r.position_itrs_km()) for r in mission.relays]

    def vehicle_itrs_km(t: Any) -> NDArray[np.float64]:
        # IAU 2000B nutation (within 1 mas of 2000A), as skyfield's own almanac searches
        # set it: the full series was nine tenths of the time.
        t._nutation_angles_radians = iau2000b_radians(t)
        xyz = sat.at(t).frame_xyz(itrs).km
        return np.asarray(xyz, dtype=np.float64).reshape(3, -1).T

    def visible_of(relay_km: NDArray[np.float64]) -> Callable[[Any], NDArray[np.int_]]:
        def visible(t: Any) -> NDArray[np.int_]:
            return (segment_clearance_km(vehicle_itrs_km(t), relay_km) >= clearance_km).astype(
                np.int_
            )

        visible.step_days = SCAN_STEP_S / 86400.0  # type: ignore[attr-defined]
        return visible

    visibles = [visible_of(r) for r in relays_km]
    total_s = (scan_to - scan_from).total_seconds()
    # Per relay: its state at the scan's start and every change after, in order.
    initial = [bool(f(ts.from_datetime(scan_from))[0]) for f in visibles]
    changes: list[list[tuple[datetime, bool]]] = [[] for _ in mission.relays]
    chunk_start = scan_from
    while chunk_start < scan_to:
        chunk_end = min(scan_to, chunk_start + timedelta(seconds=_CHUNK_S))
        t0, t1 = ts.from_datetime(chunk_start), ts.from_datetime(chunk_end)
        for i, f in enumerate(visibles):
            times, values = find_discrete(t0, t1, f, epsilon=EPSILON_S / 86400.0)
            changes[i].extend(zip(times.utc_datetime(), (bool(v) for v in values), strict=True))
        chunk_start = chunk_end
        if on_progress is not None:
            on_progress((chunk_end - scan_from).total_seconds(), total_s)

    spans: list[tuple[Relay, datetime, datetime]] = []
    for relay, was_visible, relay_changes in zip(mission.relays, initial, changes, strict=True):
        aos: datetime | None = None
        for moment, now_visible in relay_changes:
            if now_visible and not was_visible:
                aos = moment
            elif was_visible and not now_visible and aos is not None:
                if start_utc <= aos < end_utc:
                    spans.append((relay, aos, moment))
                aos = None
            was_visible = now_visible
        if aos is not None and aos < end_utc:
            raise InvalidSpan(
                f"{relay.name} acquired at {format_utc(aos)} is not lost within two orbits: "
                "continuous visibility is not a window this computes"
            )
    spans.sort(key=lambda s: (s[1], s[0].name))
    return _with_ranges(mission, spans, vehicle_itrs_km, ts)


def _terminal_itrs_km(mission: Mission) -> NDArray[np.float64]:
    """The ground terminal's position, Earth-fixed (ITRS), km."""
    from skyfield.api import wgs84

    terminal = mission.ground.terminal
    return np.asarray(
        wgs84.latlon(
            terminal.latitude_deg, terminal.longitude_deg, elevation_m=terminal.altitude_m
        ).itrs_xyz.km,
        dtype=np.float64,
    )


def _sample_grid(duration_s: float, step_s: float) -> NDArray[np.float64]:
    """Seconds from 0 to ``duration_s``, both included, at most ``step_s`` apart."""
    return np.linspace(0.0, duration_s, max(2, math.ceil(duration_s / step_s) + 1))


def _with_ranges(
    mission: Mission,
    spans: list[tuple[Relay, datetime, datetime]],
    vehicle_itrs_km: Callable[[Any], NDArray[np.float64]],
    ts: Any,
) -> list[Window]:
    """Each span with its minimum and maximum range and light time, all spans' samples
    propagated in one call."""
    if not spans:
        return []
    terminal_km = _terminal_itrs_km(mission)
    grids: list[NDArray[np.float64]] = []
    for _, aos, los in spans:
        grids.append(_sample_grid((los - aos).total_seconds(), RANGE_STEP_S))
    seconds = np.concatenate(
        [
            (aos - spans[0][1]).total_seconds() + g
            for (_, aos, _), g in zip(spans, grids, strict=True)
        ]
    )
    t0 = ts.from_datetime(spans[0][1])
    positions = vehicle_itrs_km(ts.tt_jd(t0.tt + seconds / 86400.0))
    windows: list[Window] = []
    offset = 0
    for (relay, aos, los), grid in zip(spans, grids, strict=True):
        relay_km = np.array(relay.position_itrs_km())
        ranges = np.linalg.norm(positions[offset : offset + len(grid)] - relay_km, axis=1)
        offset += len(grid)
        down_km = float(np.linalg.norm(relay_km - terminal_km))
        windows.append(
            Window(
                relay=relay.name,
                aos_utc=aos,
                los_utc=los,
                min_range_km=float(ranges.min()),
                max_range_km=float(ranges.max()),
                light_time_min_s=(float(ranges.min()) + down_km) / LIGHT_SPEED_KMPS,
                light_time_max_s=(float(ranges.max()) + down_km) / LIGHT_SPEED_KMPS,
                aos_margin_s=mission.margins.aos_margin_s,
                los_margin_s=mission.margins.los_margin_s,
            )
        )
    return windows


def light_times(
    mission: Mission, window: Window, step_s: float = RANGE_STEP_S
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The one-way light time of the path vehicle -> relay -> ground terminal over
    ``window``, sampled every ``step_s`` (at least) from its acquisition to its loss, both
    included: ``(seconds since aos_utc, light time s)``. The link emulator interpolates it
    (spacecraft/contact.py)."""
    from skyfield.api import EarthSatellite
    from skyfield.framelib import itrs
    from skyfield.nutationlib import iau2000b_radians

    if not (math.isfinite(step_s) and step_s > 0):
        raise InvalidSpan(f"step {step_s!r} s must be a positive number")
    relay = next((r for r in mission.relays if r.name == window.relay), None)
    if relay is None:
        raise InvalidSpan(f"window relay {window.relay!r} is not one of the mission's relays")
    ts = _timescale()
    sat = EarthSatellite.from_satrec(mission.orbit.satrec(), ts)
    seconds = _sample_grid(window.duration_s, step_s)
    t0 = ts.from_datetime(window.aos_utc)
    t = ts.tt_jd(t0.tt + seconds / 86400.0)
    t._nutation_angles_radians = iau2000b_radians(t)  # as compute_windows places it
    vehicle_km = np.asarray(sat.at(t).frame_xyz(itrs).km, dtype=np.float64).reshape(3, -1).T
    relay_km = np.array(relay.position_itrs_km())
    terminal_km = _terminal_itrs_km(mission)
    path_km = np.linalg.norm(vehicle_km - relay_km, axis=1) + float(
        np.linalg.norm(relay_km - terminal_km)
    )
    return seconds, np.asarray(path_km / LIGHT_SPEED_KMPS, dtype=np.float64)
