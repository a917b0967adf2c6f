"""The sections of the demo's summary (``OUT/summary.json``), pure: the documents the
ground's routes served and the spacecraft's truth log in, JSON out.

Onboard times are seconds since the spacecraft's start (:class:`OnboardClock`: the truth
log's ``start``, and the link's clock mapping for the ground's own times);
:func:`segments_section` the plan's segments on that clock, :func:`alarms_section` every
alarm with its bands' crossings, :func:`safing_section` the vehicle's safing as the ground
heard it and as the truth log tells it, and :func:`verdict` the exit status's reasons.
"""

from __future__ import annotations

import contextlib
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from planner.limits import SEVERITY_RANK, Severity

__all__ = [
    "TERMINAL_STATES",
    "OnboardClock",
    "alarms_section",
    "read_truth_log",
    "safing_section",
    "segments_section",
    "verdict",
]

#: The states a pass ends in (``safed``: the vehicle safed itself; the ground stopped it).
TERMINAL_STATES = ("complete", "aborted", "safed")
#: The audit events that tell the vehicle's safing and the pass's end.
_SAFING_EVENTS = (
    "vehicle_safed",
    "vehicle_safe_exit_requested",
    "vehicle_safe_exited",
    "vehicle_safe_exit_unverified",
)


@dataclass(frozen=True)
class OnboardClock:
    """Onboard times as seconds since the spacecraft's start (``start_ns``: the truth log's
    ``start``; None when it could not be read), and ground times on the onboard clock: the
    link's mapping read ``onboard_ns`` at the ground instant ``ground_ns`` and runs at
    ``scale`` (``uncertainty_s``: onboard s, half the wall time the read took, scaled)."""

    start_ns: int | None = None
    ground_ns: int | None = None
    onboard_ns: int | None = None
    scale: float | None = None
    uncertainty_s: float | None = None

    def since_start_s(self, onboard_ns: int | None) -> float | None:
        """Onboard s since the spacecraft's start (ms), or None where the demo cannot say."""
        if onboard_ns is None or self.start_ns is None:
            return None
        return round((onboard_ns - self.start_ns) / 1e9, 3)

    def ground_s(self, ground_ns: int | None) -> float | None:
        """A ground (wall clock) instant as onboard s since the spacecraft's start."""
        if ground_ns is None or self.ground_ns is None or self.onboard_ns is None:
            return None
        if self.scale is None:
            return None
        return self.since_start_s(
            self.onboard_ns + round((ground_ns - self.ground_ns) * self.scale)
        )


def read_truth_log(path: Path) -> list[dict[str, Any]]:
    """The truth log's records (none when there is no file; a line cut short by a stopped
    process is left out)."""
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        return []
    records = []
    for line in text.splitlines():
        with contextlib.suppress(ValueError):
            record = json.loads(line)
            if isinstance(record, dict):
                records.append(record)
    return records


def _truth_start_ns(truth: Sequence[Mapping[str, Any]]) -> int | None:
    start = next((r for r in truth if r.get("event") == "start"), None)
    return None if start is None else int(start["onboard_time_ns"])


def segments_section(
    segments: Sequence[Mapping[str, Any]], epoch_ns: int, clock: OnboardClock
) -> list[dict[str, Any]]:
    """The plan's segments (plan s) with their onboard s since the spacecraft's start."""

    def onboard(t_s: float) -> float | None:
        return clock.since_start_s(epoch_ns + round(t_s * 1e9))

    return [
        {
            "name": s["name"],
            "kind": s["kind"],
            "t_start_s": s["t_start_s"],
            "t_end_s": s["t_end_s"],
            "onboard_start_s": onboard(float(s["t_start_s"])),
            "onboard_end_s": onboard(float(s["t_end_s"])),
        }
        for s in segments
    ]


def _rank(severity: str | None) -> int:
    return 0 if severity is None else SEVERITY_RANK[Severity(severity)]


def alarms_section(alarms: Sequence[Mapping[str, Any]], clock: OnboardClock) -> dict[str, Any]:
    """Every alarm of the pass, oldest raised first, with the times that tell a rehearsal:
    ``raised_frame_s`` (the frame the ground raised it on, generated at that onboard s since
    the spacecraft's start), ``raised_ground_s`` (when the ground raised it, on the onboard
    clock), ``crossings`` (each band reached: the onboard s of the first frame in it, or, for
    the link's health, when the ground saw it) and the timeline so converted; how many went
    above ``watch``. A frame that jumps bands is in the timeline once, at the band it
    reached, and so crosses only that band here."""
    items: list[dict[str, Any]] = []
    for alarm in sorted(alarms, key=lambda a: (a["raised_time_ns"], a["id"])):
        timeline = []
        crossings: dict[str, float | None] = {}
        for step in alarm.get("timeline") or []:
            frame_s = clock.since_start_s(step.get("generation_time_ns"))
            ground_s = clock.ground_s(step.get("time_ns"))
            severity = step.get("severity")
            timeline.append({**step, "frame_s": frame_s, "ground_s": ground_s})
            if severity is not None and severity not in crossings:
                crossings[severity] = frame_s if frame_s is not None else ground_s
        items.append(
            {
                **{k: alarm.get(k) for k in _ALARM_KEYS},
                "raised_frame_s": clock.since_start_s(alarm.get("raised_generation_time_ns")),
                "raised_ground_s": clock.ground_s(alarm.get("raised_time_ns")),
                "crossings": crossings,
                "timeline": timeline,
            }
        )
    by_severity: dict[str, int] = {}
    for item in items:
        by_severity[item["severity"]] = by_severity.get(item["severity"], 0) + 1
    watch = SEVERITY_RANK[Severity.WATCH]
    return {
        "count": len(items),
        "above_watch": sum(1 for item in items if _rank(item["severity"]) > watch),
        "by_severity": by_severity,
        "items": items,
    }


_ALARM_KEYS = (
    "id",
    "quantity",
    "channel",
    "label",
    "unit",
    "source",
    "severity",
    "current_severity",
    "state",
    "limit",
    "trigger_value",
    "worst_value",
    "raised_frame_seq",
    "raised_generation_time_ns",
    "raised_time_ns",
    "detail",
)


def safing_section(
    *,
    record: Mapping[str, Any],
    link: Mapping[str, Any],
    alarms: Sequence[Mapping[str, Any]],
    events: Sequence[Mapping[str, Any]],
    truth: Sequence[Mapping[str, Any]],
    executed: Sequence[Mapping[str, Any]],
    cancelled: Sequence[Mapping[str, Any]],
    clock: OnboardClock,
) -> dict[str, Any]:
    """The vehicle's safing during the demo: from the pass's ``vehicle_safed`` event (the
    trigger, the onboard time it entered SAFE, the commands it dropped), else the link
    status's last ``safing`` report (a spacecraft process lives for one demo: any report is
    of this run); when the ground heard it (its ``vehicle_safing`` alarm was raised on the
    report's arrival; the event is written later, behind the archive's queue) and when the
    pass ended (its ``pass_state`` event); the pass's state and reason; the truth log's
    faults and SAFE entries; ``commands_executed_after_safing``, the pass's executed
    commands whose onboard execution came after the vehicle entered SAFE (must be 0)."""
    report = link.get("safing")
    safed_events = [e for e in events if e["kind"] == "vehicle_safed"]
    first = safed_events[0] if safed_events else None
    source: Mapping[str, Any] = first["detail"] if first is not None else (report or {})
    since_ns = source.get("since_time_ns")
    after = None
    if since_ns is not None:
        after = sum(
            1
            for c in executed
            if c["stage"] == "executed"
            and (c["executed_at_ns"] if c["executed_at_ns"] is not None else c["execute_time_ns"])
            > since_ns
        )
    heard = next(
        (
            a
            for a in alarms
            if a["quantity"] == "vehicle_safing" and a["raised_generation_time_ns"] == since_ns
        ),
        None,
    )
    heard_ns = heard["raised_time_ns"] if heard is not None else None
    if heard_ns is None and first is not None:
        heard_ns = first["time_ns"]
    ended = next(
        (
            e
            for e in events
            if e["kind"] == "pass_state" and e["detail"].get("to") in TERMINAL_STATES
        ),
        None,
    )
    ended_ns = None if ended is None else ended["time_ns"]
    return {
        "safed": since_ns is not None,
        "pass_state": record["state"],
        "pass_reason": record.get("state_reason"),
        "vehicle_mode": link.get("vehicle_mode"),
        "trigger": source.get("trigger"),
        "since_time_ns": since_ns,
        "since_s": clock.since_start_s(since_ns),
        "cancelled_on_board": source.get("cancelled"),
        "ground_heard_time_ns": heard_ns,
        "ground_heard_s": clock.ground_s(heard_ns),
        "pass_ended_time_ns": ended_ns,
        "pass_ended_s": clock.ground_s(ended_ns),
        "last_report": report,
        "events": [
            {
                "kind": e["kind"],
                "time_ns": e["time_ns"],
                "ground_s": clock.ground_s(e["time_ns"]),
                "detail": e["detail"],
            }
            for e in events
            if e["kind"] in _SAFING_EVENTS
            or (e["kind"] == "pass_state" and e["detail"].get("to") in TERMINAL_STATES)
        ],
        "truth_start_ns": clock.start_ns,
        "truth_faults": [r for r in truth if r.get("event") == "fault"],
        "truth_safing": [r for r in truth if r.get("event") in ("safing_entry", "safing_exit")],
        "commands_executed_after_safing": after,
        "commands_cancelled_safing": sum(
            1 for c in cancelled if c["stage"] == "cancelled" and c["reject_reason"] == "safing"
        ),
        "clock_mapping_uncertainty_s": clock.uncertainty_s,
    }


def verdict(summary: Mapping[str, Any]) -> dict[str, Any]:
    """The exit status and what happened. Without faults (a nominal demo): ``ok`` iff the
    pass ended ``complete``, its outcome ``nominal`` (every command executed at its tag:
    docs/operations.md), with no frame missing. With ``--fault``: ``ok`` iff it ended
    ``safed`` or ``complete`` and the run was otherwise sound: every fault began (the truth
    log says so), no frame of the pass's window missing, no command left outstanding, and no
    command executed after the vehicle safed. ``notes`` say what happened (the alarms above
    ``watch``, the faults, the safing), ``problems`` why it is not ``ok``."""
    state = summary["final_state"]
    safing = summary["safing"]
    faults = list(summary.get("faults") or ())
    notes = [_alarms_note(summary["alarms"])]
    problems = []
    for fault in safing["truth_faults"]:
        notes.append(f"fault {fault['spec']} began at onboard {fault['onboard_s']:.2f} s")
    if safing["safed"]:
        notes.append(_safing_note(safing))
    else:
        notes.append("the vehicle never safed itself")
    reason = f": {summary['state_reason']}" if summary.get("state_reason") else ""
    notes.append(f"the pass ended {state}{reason}")
    outcome = summary.get("outcome_text")
    if outcome:
        notes.append(f"outcome {outcome}")
    if faults:
        if state not in ("safed", "complete"):
            problems.append(f"the pass ended {state}, neither safed nor complete")
        from spacecraft.faults import parse_fault

        began = {fault["spec"] for fault in safing["truth_faults"]}
        missed = [spec for spec in faults if parse_fault(spec).spec not in began]
        if missed:
            problems.append(f"never began (the truth log has no onset): {', '.join(missed)}")
        if summary["commands_outstanding"]:
            problems.append(f"{summary['commands_outstanding']} commands still outstanding")
        after = safing["commands_executed_after_safing"]
        if after:
            problems.append(f"{after} commands executed after the vehicle safed")
    elif state != "complete":
        problems.append(f"the pass ended {state}, not complete")
    elif summary.get("outcome") == "degraded":
        problems.append(f"the pass is {outcome}")
    if summary["frames_missing"] != 0:
        problems.append(f"frames missing: {summary['frames_missing']}")
    return {"ok": not problems, "notes": notes, "problems": problems}


def _alarms_note(alarms: Mapping[str, Any]) -> str:
    watch = SEVERITY_RANK[Severity.WATCH]
    above = [a for a in alarms["items"] if _rank(a["severity"]) > watch]
    if not above:
        return f"0 alarms above watch ({alarms['count']} in all)"
    listed = "; ".join(_describe_alarm(a) for a in above)
    return f"{len(above)} alarms above watch: {listed}"


def _describe_alarm(alarm: Mapping[str, Any]) -> str:
    where = " ".join(p for p in (alarm["quantity"], alarm["channel"]) if p)
    bits = []
    if alarm["worst_value"] is not None:
        bits.append(f"worst {alarm['worst_value']:.4g} {alarm['unit']}".rstrip())
    if alarm["limit"] is not None:
        bits.append(f"limit {alarm['limit']:.4g}")
    return f"{where} {alarm['severity']}" + (f" ({', '.join(bits)})" if bits else "")


def _safing_note(safing: Mapping[str, Any]) -> str:
    when = "" if safing["since_s"] is None else f" at onboard {safing['since_s']:.2f} s"
    text = f"the vehicle safed itself{when}"
    trigger = safing["trigger"]
    if trigger:
        where = " ".join(p for p in (trigger["quantity"], trigger["channel"]) if p)
        text += f" ({where} {trigger['value']:.4g} beyond {trigger['limit']:.4g})"
    if safing["cancelled_on_board"] is not None:
        text += f", dropping {safing['cancelled_on_board']} commands"
    after = safing["commands_executed_after_safing"]
    return text + f"; {after if after is not None else 'unknown'} executed after"
