"""Alarm documents (``server.storage.alarms.alarm_document``'s shape) for the tests that
store, record or report alarms: joint3's tracking error, the values a test asserts given."""

from __future__ import annotations

import uuid
from typing import Any


def alarm_doc(pass_id: str | None, *, now_ns: int, **overrides: Any) -> dict[str, Any]:
    """A triggered watch alarm of joint3's tracking error, raised at frame 5 at ``now_ns``;
    ``overrides`` replace any field."""
    doc: dict[str, Any] = {
        "id": str(uuid.uuid4()),
        "pass_id": pass_id,
        "quantity": "joint_tracking_error_deg",
        "channel": "joint3",
        "label": "joint tracking error",
        "unit": "deg",
        "direction": "high",
        "source": "limit",
        "severity": "watch",
        "current_severity": "watch",
        "state": "triggered",
        "acknowledged": False,
        "acknowledged_by": None,
        "acknowledged_time_ns": None,
        "comment": None,
        "limit": 2.0,
        "trigger_value": 2.5,
        "worst_value": 2.5,
        "last_value": 2.5,
        "count": 1,
        "raised_frame_seq": 5,
        "raised_generation_time_ns": 500,
        "raised_time_ns": now_ns,
        "updated_time_ns": now_ns,
        "cleared_generation_time_ns": None,
        "cleared_time_ns": None,
        "timeline": [
            {
                "severity": "watch",
                "generation_time_ns": 500,
                "time_ns": now_ns,
                "frame_seq": 5,
                "value": 2.5,
            }
        ],
        "detail": None,
    }
    doc.update(overrides)
    return doc


def cleared_alarm(pass_id: str | None, **fields: Any) -> dict[str, Any]:
    """Joint3's tracking alarm over its 5 deg limit: it reached critical, has cleared and was
    acknowledged; ``fields``: its times, values, timeline and acknowledgement."""
    return alarm_doc(
        pass_id,
        now_ns=fields.get("raised_time_ns", 0),
        severity="critical",
        current_severity=None,
        state="cleared",
        acknowledged=True,
        limit=5.0,
        **fields,
    )
