"""The sentences a pass's record carries when the ground hands it to the vehicle (a graceful
stop) or the vehicle safes itself (:mod:`server.services.runner`)."""

from __future__ import annotations

from datetime import UTC, datetime

from telemetry.wire import Safing

__all__ = ["handover_reason", "safed_reason"]


def handover_reason(
    onboard_ns: int | None, first_tag_ns: int | None, loaded: int, unsent: int, policy: str
) -> str:
    """The ``ground_stopped`` event's sentence: when the pass was handed to the vehicle,
    what it holds, and the policy it flies under."""
    at = "an unknown onboard time"
    if onboard_ns is not None:
        at = datetime.fromtimestamp(onboard_ns / 1e9, UTC).strftime("%Y-%m-%d %H:%M:%S.%f")
        at = f"onboard {at[:-4]} UTC"
        if first_tag_ns is not None:
            at += f" (t = {(onboard_ns - first_tag_ns) / 1e9:.1f} s into the pass)"
    return (
        f"ground service stopped: pass handed to the vehicle at {at}; {loaded} commands "
        f"loaded or on their way, {unsent} not sent; the vehicle's LOS policy {policy!r} "
        "applies until the ground resumes the pass"
    )


def safed_reason(report: Safing, first_tag_ns: int | None = None) -> str:
    """A safed pass's reason: the trigger and the onboard time (and, given the pass's first
    command's tag, the time into the pass)."""
    since = report.since_time_ns if report.since_time_ns is not None else report.onboard_time_ns
    at = datetime.fromtimestamp(since / 1e9, UTC).strftime("%Y-%m-%d %H:%M:%S.%f")[:-4]
    text = f"the vehicle safed itself at onboard {at} UTC"
    if first_tag_ns is not None:
        text += f" (t = {(since - first_tag_ns) / 1e9:.2f} s into the pass)"
    trigger = report.trigger
    if trigger is not None:
        where = f"{trigger.quantity} {trigger.channel}".strip()
        text += f": {where} {trigger.value:.4g} beyond its red limit {trigger.limit:.4g}"
    return text[:300]
