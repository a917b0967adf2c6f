"""Missions and their contact windows for the ground (docs/missions.md): a request names a
mission, never a file.

The server knows the mission files shipped under ``examples/missions/`` (a source checkout)
and those in its own folder (:attr:`server.settings.Settings.missions_dir`,
``HIKOBOSHI_MISSIONS_DIR``; one there shadows a shipped one of the same name). A mission's
name is its file's stem; a name is checked against ``mission.NAME`` before any path is
made of it, so a request cannot make the server read another file. Files are read when a
request needs them, never at import.

    list_missions(settings) -> MissionsPublic              GET /api/missions
    windows_job(path, start, hours) -> WindowsPublic     GET /api/windows, in a worker
    window_for_pass(settings, ref) -> (name, window)     POST /api/passes naming a window

Refusals: 404 ``unknown_mission`` (naming the known ones), 404 ``unknown_relay``, 404
``no_such_window``; 422 ``invalid_mission`` (the file does not load: file, key, reason),
``span_outside_elements`` (a time too far from the elements' epoch) and, for a pass,
``time_out_of_range`` (outside 1970..2200, as a hand-given window's).
"""

from __future__ import annotations

from datetime import timedelta
from pathlib import Path
from typing import Any

from mission import (
    MAX_HOURS,
    MISSIONS_DIR,
    NAME,
    InvalidMission,
    InvalidSpan,
    Mission,
    Window,
    compute_windows,
    load_mission,
)
from mission.windows import MAX_EPOCH_DISTANCE_DAYS
from server.schemas import EARLIEST, LATEST, ns_from_datetime
from server.schemas.passes import (
    MissionPublic,
    MissionRelayPublic,
    MissionsPublic,
    MissionUnloadablePublic,
    WindowPublic,
    WindowRef,
    WindowsPublic,
)
from server.services.errors import InvalidRequestError, NotFoundError
from server.settings import Settings

__all__ = [
    "MAX_WINDOW_HOURS",
    "WINDOW_MATCH_S",
    "known_missions",
    "list_missions",
    "resolve_mission",
    "window_for_pass",
    "windows_job",
]

#: The longest span ``GET /api/windows`` computes: a week (0.9 s on this machine,
#: bench/bench_windows.py).
MAX_WINDOW_HOURS = 168.0
#: A pass names a window by its acquisition time, to within this much.
WINDOW_MATCH_S = 120.0


def _folders(settings: Settings) -> list[Path]:
    folders = [MISSIONS_DIR]
    if settings.missions_dir is not None:
        folders.append(settings.missions_dir)
    return folders


def known_missions(settings: Settings) -> dict[str, Path]:
    """Mission name -> its file: the shipped ones, then the server's folder's."""
    found: dict[str, Path] = {}
    for folder in _folders(settings):
        if not folder.is_dir():
            continue
        for path in sorted(folder.glob("*.toml")):
            if NAME.match(path.stem) and path.is_file():
                found[path.stem] = path.resolve()
    return found


def resolve_mission(settings: Settings, name: str) -> Path:
    """The file of the mission ``name``; 404 ``unknown_mission`` naming the known ones."""
    missions = known_missions(settings) if NAME.match(name) else {}
    if name not in missions:
        raise NotFoundError(
            "unknown_mission",
            f"no mission named {name!r} on this server; it knows "
            f"{sorted(known_missions(settings))}",
        )
    return missions[name]


def _mission_public(mission: Mission) -> MissionPublic:
    epoch = mission.orbit.epoch_utc
    reach = timedelta(days=MAX_EPOCH_DISTANCE_DAYS)
    return MissionPublic(
        name=mission.name,
        description=mission.description,
        vehicle=mission.vehicle,
        mission_sha256=mission.content_sha256,
        epoch=epoch,
        windows_from=epoch - reach,
        windows_until=epoch + reach,
        relays=[
            MissionRelayPublic(name=r.name, satellite=r.satellite, longitude_deg=r.longitude_deg)
            for r in mission.relays
        ],
        station=mission.ground.station,
        processing_delay_s=mission.ground.processing_delay_s,
        aos_margin_s=mission.margins.aos_margin_s,
        los_margin_s=mission.margins.los_margin_s,
    )


def list_missions(settings: Settings) -> MissionsPublic:
    """Every mission the server knows, by name, each file read now (about 1 ms a file,
    docs/missions.md); a file that does not load is listed in ``unloadable`` with its key
    and reason, not refused."""
    loaded: list[MissionPublic] = []
    unloadable: list[MissionUnloadablePublic] = []
    for name, path in known_missions(settings).items():
        try:
            loaded.append(_mission_public(load_mission(path)))
        except InvalidMission as exc:
            unloadable.append(MissionUnloadablePublic(name=name, reason=f"{exc.key}: {exc.reason}"))
    return MissionsPublic(
        data=loaded,
        count=len(loaded),
        unloadable=unloadable,
        max_hours=min(MAX_WINDOW_HOURS, MAX_HOURS),
    )


def _load(path: Path) -> Mission:
    try:
        return load_mission(path)
    except InvalidMission as exc:
        raise InvalidRequestError(
            "invalid_mission",
            f"mission {path.stem} does not load: {exc.key}: {exc.reason}",
            {"mission": path.stem, "key": exc.key, "reason": exc.reason},
        ) from None


def _compute(mission: Mission, start: Any, hours: float) -> list[Window]:
    try:
        return compute_windows(mission, start, hours)
    except InvalidSpan as exc:
        raise InvalidRequestError("span_outside_elements", str(exc)) from None


def _public(window: Window) -> WindowPublic:
    return WindowPublic(
        relay=window.relay,
        aos_time=window.aos_utc,
        los_time=window.los_utc,
        duration_s=window.duration_s,
        net_start_time=window.net_start_utc,
        net_end_time=window.net_end_utc,
        net_s=window.net_s,
        min_range_km=window.min_range_km,
        max_range_km=window.max_range_km,
        light_time_min_s=window.light_time_min_s,
        light_time_max_s=window.light_time_max_s,
    )


def windows_job(path: str, start: Any, hours: float) -> WindowsPublic:
    """The windows of the mission at ``path`` (resolved by name) with AOS in ``[start,
    start + hours)``: what ``GET /api/windows`` answers (run in a worker process)."""
    mission = _load(Path(path))
    found = _compute(mission, start, hours)
    return WindowsPublic(
        mission=mission.name,
        mission_sha256=mission.content_sha256,
        vehicle=mission.vehicle,
        start=start,
        hours=hours,
        processing_delay_s=mission.ground.processing_delay_s,
        aos_margin_s=mission.margins.aos_margin_s,
        los_margin_s=mission.margins.los_margin_s,
        data=[_public(w) for w in found],
        count=len(found),
    )


def window_for_pass(settings: Settings, ref: WindowRef) -> tuple[Window, dict[str, Any]]:
    """The computed window ``ref`` names (its relay's window acquiring within
    ``WINDOW_MATCH_S`` of ``ref.aos_time``) and the document stored with the pass."""
    if not EARLIEST <= ref.aos_time < LATEST:
        raise InvalidRequestError(
            "time_out_of_range", f"window.aos_time {ref.aos_time.isoformat()} is outside 1970..2200"
        )
    mission = _load(resolve_mission(settings, ref.mission))
    if ref.relay not in {r.name for r in mission.relays}:
        raise NotFoundError(
            "unknown_relay",
            f"mission {mission.name} has no relay {ref.relay!r}; it has "
            f"{[r.name for r in mission.relays]}",
        )
    match = timedelta(seconds=WINDOW_MATCH_S)
    around = _compute(mission, ref.aos_time - match, 2 * WINDOW_MATCH_S / 3600.0)
    candidates = [w for w in around if w.relay == ref.relay]
    if not candidates:
        raise NotFoundError(
            "no_such_window",
            f"{ref.relay} of mission {mission.name} acquires no window within "
            f"{WINDOW_MATCH_S:g} s of {ref.aos_time.isoformat()} (GET /api/windows lists them)",
        )
    window = min(candidates, key=lambda w: abs((w.aos_utc - ref.aos_time).total_seconds()))
    document = {
        "mission": mission.name,
        "mission_sha256": mission.content_sha256,
        "relay": window.relay,
        "aos_time_ns": ns_from_datetime(window.aos_utc),
        "los_time_ns": ns_from_datetime(window.los_utc),
        "aos_margin_s": window.aos_margin_s,
        "los_margin_s": window.los_margin_s,
        "net_s": window.net_s,
        "min_range_km": window.min_range_km,
        "max_range_km": window.max_range_km,
        "light_time_min_s": window.light_time_min_s,
        "light_time_max_s": window.light_time_max_s,
        "processing_delay_s": mission.ground.processing_delay_s,
    }
    return window, document
