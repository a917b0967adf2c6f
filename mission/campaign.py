"""A campaign's orbit side: the windows its passes take, what the orbit loads into the wheels
between two passes, and the campaign file read back (docs/missions.md, Campaigns; SPEC
sections 2 and 8).

    next_window(windows, not_before_utc, needed_s) -> Window | None
    inverse_cube_radius_s_per_m3(mission, start_utc, end_utc) -> float   integral |r|^-3 dt
    load_campaign(path) -> CampaignRecord            campaign.json, as written

Between passes the arm rests and attitude control holds the base at its target in the
Earth-pointing orbit frame, so the wheels absorb the gravity-gradient torque of SPEC eq. (11),
``N = 3 mu / |r|^3 * r_hat x (H_c r_hat)`` (base frame), and eq. (14) accumulates it:
``dL = N dt``. ``|r|`` is the vehicle's distance from the Earth's centre along the mission's
own SGP4 propagation (not a constant radius); ``r_hat`` in the base frame is the nadir axis
seen from the held attitude. As in the passes' predictions, the orbit frame is taken as
inertial (SPEC 2): the orbit rate's gyroscopic share is left out (docs/missions.md says how
large it is).

The package imports nothing else of ours (an import contract), so the planning itself and
eq. (11) over a gap, which need the planner, live in :mod:`server.operations.campaign`
(``plan_campaign``) and :mod:`server.operations.campaign_gap`; this module holds what needs
only the orbit. Nothing is read at import.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime, timedelta
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mission.errors import MissionError
from mission.file import Mission
from mission.windows import Window, format_utc, parse_utc

__all__ = [
    "CAMPAIGN_FORMAT_VERSION",
    "GAP_STEP_S",
    "CampaignPassRecord",
    "CampaignRecord",
    "InvalidCampaign",
    "StateRecord",
    "inverse_cube_radius_s_per_m3",
    "load_campaign",
    "next_window",
    "orbit_radius_m",
    "window_from_dict",
]

#: The longest step of the gap's integration (Simpson's rule over SGP4 radii); the radius
#: changes over an orbit of about 5700 s, so the rule's error is far below a micro-N m s.
GAP_STEP_S = 10.0
CAMPAIGN_FORMAT_VERSION = 1
#: A campaign file is refused by its size before it is read.
MAX_CAMPAIGN_BYTES = 4 * 1024 * 1024

Array = NDArray[np.float64]

_UNIX_EPOCH_JD = 2440587.5


class InvalidCampaign(MissionError, ValueError):
    """A campaign file that cannot be read back: ``file: reason``."""


def next_window(
    windows: Sequence[Window], not_before_utc: datetime, needed_s: float = 0.0
) -> Window | None:
    """The first window (by net start) whose net time starts at or after ``not_before_utc``
    and holds at least ``needed_s``; ``None`` when there is none."""
    for window in sorted(windows, key=lambda w: (w.net_start_utc, w.relay)):
        if window.net_start_utc >= not_before_utc and window.net_s >= needed_s:
            return window
    return None


def orbit_radius_m(mission: Mission, times_utc: Sequence[datetime]) -> Array:
    """The vehicle's distance from the Earth's centre (m) at each time, by SGP4 on the
    mission's own element set (TEME positions); MissionError if SGP4 fails."""
    satrec = mission.orbit.satrec()
    jd = np.array([t.timestamp() / 86400.0 + _UNIX_EPOCH_JD for t in times_utc])
    whole = np.floor(jd)
    errors, positions_km, _ = satrec.sgp4_array(whole, jd - whole)
    if np.any(errors != 0):
        bad = int(np.flatnonzero(errors)[0])
        raise MissionError(
            f"SGP4 fails at {format_utc(times_utc[bad])} (error code {int(errors[bad])})"
        )
    return np.asarray(np.linalg.norm(positions_km, axis=1) * 1000.0, dtype=np.float64)


def inverse_cube_radius_s_per_m3(
    mission: Mission, start_utc: datetime, end_utc: datetime, *, max_step_s: float = GAP_STEP_S
) -> float:
    """``integral |r|^-3 dt`` from ``start_utc`` to ``end_utc`` (s/m^3): ``|r|`` from SGP4
    every ``max_step_s`` at most, Simpson's rule. Eq. (11)'s torque over a gap, ``3 mu /
    |r|^3 * r_hat x (H_c r_hat)`` with the attitude held, is this times ``3 mu r_hat x (H_c
    r_hat)`` (:func:`server.operations.campaign_gap.gravity_gradient_momentum_nms`)."""
    span_s = (end_utc - start_utc).total_seconds()
    if not math.isfinite(span_s) or span_s < 0.0:
        raise MissionError(
            f"a gap from {format_utc(start_utc)} to {format_utc(end_utc)} runs backwards"
        )
    if span_s == 0.0:
        return 0.0
    intervals = max(2, 2 * math.ceil(span_s / (2.0 * max_step_s)))  # even, for Simpson
    offsets_s = np.linspace(0.0, span_s, intervals + 1)
    radius_m = orbit_radius_m(mission, [start_utc + timedelta(seconds=float(s)) for s in offsets_s])
    weights = np.ones(intervals + 1)
    weights[1:-1:2] = 4.0
    weights[2:-1:2] = 2.0
    return float(np.sum(weights * radius_m**-3.0)) * (span_s / intervals) / 3.0


def window_from_dict(doc: Mapping[str, Any]) -> Window:
    """A window as ``Window.to_dict()`` wrote it (times to the millisecond)."""
    aos = parse_utc(str(doc["aos_utc"]))
    los = parse_utc(str(doc["los_utc"]))
    return Window(
        relay=str(doc["relay"]),
        aos_utc=aos,
        los_utc=los,
        min_range_km=float(doc["min_range_km"]),
        max_range_km=float(doc["max_range_km"]),
        light_time_min_s=float(doc["light_time_min_s"]),
        light_time_max_s=float(doc["light_time_max_s"]),
        aos_margin_s=(parse_utc(str(doc["net_start_utc"])) - aos).total_seconds(),
        los_margin_s=(los - parse_utc(str(doc["net_end_utc"]))).total_seconds(),
    )


@dataclass(frozen=True, eq=False)
class StateRecord:
    """A predicted vehicle state as the campaign file holds it (the fields of
    ``planner.state.VehicleState``): arm joints (rad), base attitude (orbit from base,
    x y z w), base rate (orbit frame, rad/s), wheel momentum (base frame, N m s)."""

    joints_rad: Array
    quat_orbit_from_base_xyzw: Array
    omega_base_orbit_radps: Array
    wheel_momentum_nms: Array


@dataclass(frozen=True, eq=False)
class CampaignPassRecord:
    """One pass of a campaign file: its window, experiments, plan file and states."""

    index: int
    window: Window
    experiments: tuple[str, ...]
    plan_path: Path
    plan_start_utc: datetime
    plan_end_utc: datetime
    start_state: StateRecord
    end_state: StateRecord
    gap_s: float
    gap_momentum_nms: Array
    gap_gravity_gradient_nms: Array
    flight_rules_passed: bool | None


@dataclass(frozen=True, eq=False)
class CampaignRecord:
    """A campaign file read back (``load_campaign``)."""

    path: Path
    mission: str
    mission_sha256: str
    start_utc: datetime
    robot: str
    robot_hash: str
    passes: tuple[CampaignPassRecord, ...]
    document: Mapping[str, Any]


def _state(doc: Mapping[str, Any]) -> StateRecord:
    shapes = {
        "quat_orbit_from_base_xyzw": (4,),
        "omega_base_orbit_radps": (3,),
        "wheel_momentum_nms": (3,),
    }
    values = {}
    for name in ("joints_rad", *shapes):
        value = np.array(doc[name], dtype=np.float64)
        expected = shapes.get(name)
        if (expected is not None and value.shape != expected) or value.ndim != 1:
            raise ValueError(f"{name} has shape {value.shape}")
        if not np.all(np.isfinite(value)):
            raise ValueError(f"{name} is not finite")
        values[name] = value
    return StateRecord(**values)


def _vector(doc: Mapping[str, Any], name: str) -> Array:
    value = np.array(doc[name], dtype=np.float64)
    if value.shape != (3,) or not np.all(np.isfinite(value)):
        raise ValueError(f"{name} must be a finite 3-vector")
    return value


def load_campaign(path: Path | str) -> CampaignRecord:
    """The campaign file at ``path`` (``campaign.json`` as ``Campaign.write`` wrote it),
    plan paths resolved beside it; :class:`InvalidCampaign` naming the file and the fault."""
    path = Path(path)
    try:
        size = path.stat().st_size
        if size > MAX_CAMPAIGN_BYTES:
            raise InvalidCampaign(f"{path}: {size} bytes, over the {MAX_CAMPAIGN_BYTES} limit")
        doc = json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise InvalidCampaign(f"{path}: {exc.strerror}") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InvalidCampaign(f"{path}: not JSON: {exc}") from None
    if not isinstance(doc, dict):
        raise InvalidCampaign(f"{path}: a campaign is a JSON object")
    if doc.get("format_version") != CAMPAIGN_FORMAT_VERSION:
        raise InvalidCampaign(
            f"{path}: format_version {doc.get('format_version')!r} is not {CAMPAIGN_FORMAT_VERSION}"
        )
    try:
        passes = []
        for item in doc["passes"]:
            passes.append(
                CampaignPassRecord(
                    index=int(item["index"]),
                    window=window_from_dict(item["window"]),
                    experiments=tuple(str(e) for e in item["experiments"]),
                    plan_path=path.parent / Path(str(item["plan_file"])).name,
                    plan_start_utc=parse_utc(str(item["plan_start_utc"])),
                    plan_end_utc=parse_utc(str(item["plan_end_utc"])),
                    start_state=_state(item["start_state"]),
                    end_state=_state(item["end_state"]),
                    gap_s=float(item["gap_s"]),
                    gap_momentum_nms=_vector(item, "gap_momentum_nms"),
                    gap_gravity_gradient_nms=_vector(item, "gap_gravity_gradient_nms"),
                    flight_rules_passed=item.get("flight_rules_passed"),
                )
            )
        return CampaignRecord(
            path=path,
            mission=str(doc["mission"]),
            mission_sha256=str(doc["mission_sha256"]),
            start_utc=parse_utc(str(doc["start_utc"])),
            robot=str(doc["robot"]),
            robot_hash=str(doc["robot_hash"]),
            passes=tuple(passes),
            document=doc,
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise InvalidCampaign(f"{path}: malformed campaign: {exc!r}") from None
