"""A pass as one MCAP file: export for Foxglove and archives, import back, bit for bit.

:func:`write_mcap` writes a :class:`~telemetry.recording.PassRecording`;
:func:`read_mcap` gives back exactly that recording (every array bitwise equal, the plan's
JSON identical, commands, events and meta equal). ``docs/mcap.md`` is the user's guide.

Every message is JSON (``json`` message encoding) with a JSON schema (``jsonschema``
encoding). The log time of each message is the time of what it records, on the clock named
in the channel's ``clock`` metadata; publish time equals log time.

Our channels (read back; all required)::

    /hikoboshi/telemetry  hikoboshi.TelemetryFrame  one per frame; log time = generation time
                                                    (onboard); reception_time_ns inside (ground)
    /hikoboshi/commands   hikoboshi.Command         one per command with its stage times;
                                                    log time = execute_time_ns (onboard tag)
    /hikoboshi/events     hikoboshi.Event           one per audit event; log time = time_ns
                                                    (ground)
    /hikoboshi/plan       hikoboshi.Plan            the plan with its prediction, exactly
                                                    Plan.to_json(); log time = epoch_ns
                                                    (onboard time of the plan's t = 0)

Derived channels (for viewing; not read back)::

    /tf                   foxglove.FrameTransforms  per frame: orbit -> base_link (recorded
                                                    attitude), then every URDF link; onboard
    /robot_description    std_msgs/String           the URDF, once, at the file's first log time
    /robot_meshes         foxglove.SceneUpdate      a vendor robot's visual meshes, embedded,
                                                    once, on their links' /tf frames (only
                                                    when the robot has meshes)
    /plot/joints, /plot/base, /plot/wheels          flat numbers per frame, degrees; onboard
    /plot/prediction                                the plan's prediction; onboard
                                                    (epoch_ns + t_s)
    /events               foxglove.Log              one per audit event (level by kind, the
                                                    actor as name); ground (only when the
                                                    pass has events)
    /alarms               foxglove.Log              the pass's alarms: each change of band and
                                                    each acknowledgement; onboard (only when
                                                    the pass has alarms)

The metadata record ``hikoboshi.recording`` marks the file as ours and holds the name,
``epoch_ns``, ``meta`` (as JSON), the message counts and, when the pass has alarms, the
alarms (``alarms_json``: their documents, read back exactly); the URDF of the model is also the
attachment ``<robot>.urdf``, named after the plan's robot (``ets7.urdf``, ``orihime.urdf``;
:func:`read_urdf` finds it, and ``ets7.urdf`` in recordings written before). Chunks are
zstd-compressed, with chunk and message indexes.

Errors: one class, :class:`RecordingFileError` (a ``ValueError``), for a file that is not
MCAP, not ours, damaged or truncated, lacks a required channel, holds a message that breaks
its schema or inconsistent counts; and for a recording that JSON cannot carry exactly.
"""

from __future__ import annotations

from telemetry.mcap._errors import RecordingFileError
from telemetry.mcap._plots import PLOT_TOPICS
from telemetry.mcap._read import read_mcap, read_urdf
from telemetry.mcap._schemas import (
    METADATA_NAME,
    OWN_SCHEMAS,
    TOPIC_COMMANDS,
    TOPIC_EVENTS,
    TOPIC_PLAN,
    TOPIC_TELEMETRY,
    URDF_ATTACHMENT,
    urdf_attachment_name,
)
from telemetry.mcap._write import (
    TOPIC_ALARMS,
    TOPIC_EVENT_LOG,
    TOPIC_ROBOT_DESCRIPTION,
    TOPIC_ROBOT_MESHES,
    TOPIC_TF,
    write_mcap,
)

__all__ = [
    "METADATA_NAME",
    "OWN_SCHEMAS",
    "PLOT_TOPICS",
    "TOPIC_ALARMS",
    "TOPIC_COMMANDS",
    "TOPIC_EVENTS",
    "TOPIC_EVENT_LOG",
    "TOPIC_PLAN",
    "TOPIC_ROBOT_DESCRIPTION",
    "TOPIC_ROBOT_MESHES",
    "TOPIC_TELEMETRY",
    "TOPIC_TF",
    "URDF_ATTACHMENT",
    "RecordingFileError",
    "read_mcap",
    "read_urdf",
    "urdf_attachment_name",
    "write_mcap",
]
