"""The relay's contact plan: when the link is up and how long a message takes, from the
mission's geometry (docs/missions.md, "The link follows the geometry").

A :class:`ContactPlan` holds contact windows in ONBOARD seconds since the link's epoch (the
spacecraft's start, which the mission start maps to UTC: ``utc = start_utc + onboard_s``)
and, for each, the one-way delay sampled along it: the ground's fixed processing delay plus
the light time of the path vehicle -> relay -> ground terminal (:func:`mission.light_times`).
The link emulator (:mod:`spacecraft.link`) asks it two things per message, both cheap (a
bisection and a linear interpolation, no geometry at run time):

- :meth:`ContactPlan.window_at` ``(t)``: the window carrying the link at ``t`` (None: no
  window, the link is down). Where two relays' windows overlap the link stays on the one
  acquired first until its loss (a handover), so a message crosses only if its whole flight,
  from hand-over to arrival, lies inside the window it was sent in;
- :meth:`ContactPlan.delay_at` ``(t)``: the one-way delay at ``t`` in that window.

:func:`contact_plan` builds one from a mission, its start and the windows to fly.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

__all__ = ["ContactPlan", "ContactWindow", "contact_plan", "load_contact", "windows_from_json"]

#: The one-way delay is sampled this often along a window (the light time changes by less
#: than 20 us a second on a LEO-GEO path: linear interpolation is exact to well under 1 us).
DELAY_STEP_S = 10.0


@dataclass(frozen=True)
class ContactWindow:
    """One window ``[start_s, end_s)`` (onboard s) through ``relay``, with the one-way delay
    sampled at ``times_s`` (ascending, from ``start_s`` to ``end_s``)."""

    relay: str
    start_s: float
    end_s: float
    times_s: tuple[float, ...]
    delays_s: tuple[float, ...]

    def __post_init__(self) -> None:
        if not (math.isfinite(self.start_s) and math.isfinite(self.end_s)):
            raise ValueError(f"window {self.relay}: start and end must be finite")
        if not self.start_s < self.end_s:
            raise ValueError(
                f"window {self.relay}: end_s = {self.end_s!r} is not after start_s = "
                f"{self.start_s!r}"
            )
        if len(self.times_s) < 2 or len(self.times_s) != len(self.delays_s):
            raise ValueError(f"window {self.relay}: needs two or more (time, delay) samples")
        if any(b <= a for a, b in zip(self.times_s, self.times_s[1:], strict=False)):
            raise ValueError(f"window {self.relay}: delay sample times must ascend")
        if any(not (math.isfinite(d) and d >= 0) for d in self.delays_s):
            raise ValueError(f"window {self.relay}: delays must be finite and >= 0")

    def contains(self, t_s: float) -> bool:
        return self.start_s <= t_s < self.end_s

    def delay_at(self, t_s: float) -> float:
        """The one-way delay at ``t_s``, linear between samples, held beyond them."""
        times = self.times_s
        i = bisect_right(times, t_s)
        if i <= 0:
            return self.delays_s[0]
        if i >= len(times):
            return self.delays_s[-1]
        t0, t1 = times[i - 1], times[i]
        d0, d1 = self.delays_s[i - 1], self.delays_s[i]
        return d0 + (d1 - d0) * (t_s - t0) / (t1 - t0)


class ContactPlan:
    """The windows the link is up in; see the module docstring."""

    def __init__(self, windows: Sequence[ContactWindow]) -> None:
        self.windows: tuple[ContactWindow, ...] = tuple(
            sorted(windows, key=lambda w: (w.start_s, w.relay))
        )
        # The timeline: consecutive pieces [start, next start), each carried by one window
        # (its index) or none (-1): the earliest-acquired window still up.
        bounds = sorted({b for w in self.windows for b in (w.start_s, w.end_s)})
        starts: list[float] = []
        carriers: list[int] = []
        for b in bounds:
            carrier = next((i for i, w in enumerate(self.windows) if w.contains(b)), -1)
            if carriers and carriers[-1] == carrier:
                continue
            starts.append(b)
            carriers.append(carrier)
        self._starts = starts
        self._carriers = carriers

    def __repr__(self) -> str:
        return f"ContactPlan({len(self.windows)} windows)"

    def window_at(self, t_s: float) -> ContactWindow | None:
        """The window carrying the link at ``t_s``, or None (no window: the link is down)."""
        i = bisect_right(self._starts, t_s) - 1
        if i < 0:
            return None
        carrier = self._carriers[i]
        return None if carrier < 0 else self.windows[carrier]

    def is_up(self, t_s: float) -> bool:
        return self.window_at(t_s) is not None

    def delay_at(self, t_s: float) -> float | None:
        """The one-way delay at ``t_s`` (None outside every window)."""
        window = self.window_at(t_s)
        return None if window is None else window.delay_at(t_s)

    def next_start_s(self, t_s: float) -> float | None:
        """The first acquisition after ``t_s`` (the link comes up from down; a handover is
        none), or None: never again."""
        i = bisect_right(self._starts, t_s)
        for j in range(i, len(self._starts)):
            if self._carriers[j] >= 0 and (j == 0 or self._carriers[j - 1] < 0):
                return self._starts[j]
        return None

    def end_of_contact_s(self, t_s: float) -> float | None:
        """When the contact carrying ``t_s`` ends (the link goes down, not a handover to
        an overlapping window); None if the link is down at ``t_s``."""
        i = bisect_right(self._starts, t_s) - 1
        if i < 0 or self._carriers[i] < 0:
            return None
        for j in range(i + 1, len(self._starts)):
            if self._carriers[j] < 0:
                return self._starts[j]
        return math.inf  # unreachable: the last bound always ends a window

    def to_dict(self) -> dict[str, Any]:
        return {
            "windows": [
                {
                    "relay": w.relay,
                    "start_s": w.start_s,
                    "end_s": w.end_s,
                    "delay_min_s": min(w.delays_s),
                    "delay_max_s": max(w.delays_s),
                }
                for w in self.windows
            ]
        }


def contact_plan(
    mission: Any, start_utc: datetime, windows: Sequence[Any], step_s: float = DELAY_STEP_S
) -> ContactPlan:
    """The contact plan of ``windows`` (:class:`mission.Window`) for a link whose onboard
    second 0 is ``start_utc``: each window's one-way delay is the mission's ground
    processing delay plus the light time of its path, sampled every ``step_s``."""
    from mission import light_times

    processing_s = float(mission.ground.processing_delay_s)
    out = []
    for window in windows:
        offsets, light = light_times(mission, window, step_s)
        start_s = (window.aos_utc - start_utc).total_seconds()
        out.append(
            ContactWindow(
                relay=window.relay,
                start_s=start_s,
                end_s=start_s + window.duration_s,
                times_s=tuple(float(start_s + o) for o in offsets),
                delays_s=tuple(float(processing_s + x) for x in light),
            )
        )
    return ContactPlan(out)


def windows_from_json(text: str, where: str = "windows") -> list[Any]:
    """The windows of a JSON document: ``hikoboshi windows --json``'s object (its
    ``windows``), a campaign's (each pass's ``window``) or a bare list of windows.
    ValueError naming ``where`` and what is wrong."""
    import json

    from mission import MissionError, Window

    try:
        doc = json.loads(text)
    except ValueError as exc:
        raise ValueError(f"{where}: not JSON: {exc}") from None
    if isinstance(doc, dict) and isinstance(doc.get("windows"), list):
        items = doc["windows"]
    elif isinstance(doc, dict) and isinstance(doc.get("passes"), list):
        items = [p.get("window") if isinstance(p, dict) else None for p in doc["passes"]]
    elif isinstance(doc, list):
        items = doc
    else:
        raise ValueError(f"{where}: neither a list of windows nor an object holding one")
    windows = []
    for i, item in enumerate(items):
        if not isinstance(item, dict):
            raise ValueError(f"{where}: window {i} is not an object")
        try:
            windows.append(Window.from_dict(item))
        except MissionError as exc:
            raise ValueError(f"{where}: window {i}: {exc}") from None
    if not windows:
        raise ValueError(f"{where}: no windows")
    return windows


def load_contact(
    mission_path: Path,
    start_utc: datetime,
    *,
    windows_path: Path | None = None,
    relays: Sequence[str] = (),
    hours: float = 24.0,
) -> ContactPlan:
    """The contact plan of a mission file for a link whose onboard second 0 is
    ``start_utc``: the windows of ``windows_path`` (:func:`windows_from_json`), else those
    computed over ``hours`` from the start; only ``relays``' when given. ValueError with
    the reason on one line."""
    from mission import MissionError, compute_windows, load_mission

    try:
        mission = load_mission(mission_path)
        if windows_path is not None:
            windows = windows_from_json(windows_path.read_text(), str(windows_path))
        else:
            windows = compute_windows(mission, start_utc, hours)
    except MissionError as exc:
        raise ValueError(str(exc)) from None
    names = {r.name for r in mission.relays}
    unknown = sorted(set(relays) - names)
    if unknown:
        raise ValueError(
            f"relay(s) {', '.join(unknown)} not in {mission_path}; it has "
            f"{', '.join(sorted(names))}"
        )
    missing = sorted({w.relay for w in windows} - names)
    if missing:
        raise ValueError(f"window relay(s) {', '.join(missing)} not in {mission_path}")
    if relays:
        windows = [w for w in windows if w.relay in relays]
    if not windows:
        raise ValueError(f"no windows of {mission_path} to fly from {start_utc.isoformat()}")
    try:
        return contact_plan(mission, start_utc, windows)
    except MissionError as exc:
        raise ValueError(str(exc)) from None
