"""MCAP export of a :class:`~telemetry.recording.PassRecording` (layout in the package doc)."""

from __future__ import annotations

import json
import os
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from typing import IO, Any

import numpy as np
from mcap.writer import CompressionType, IndexType, Writer
from numpy.typing import NDArray

from planner.meshes import MeshVisual
from planner.model import RobotModel, default_model
from planner.urdf import urdf_xml
from telemetry.foxglove import (
    FRAME_TRANSFORMS_SCHEMA,
    FRAME_TRANSFORMS_SCHEMA_NAME,
    LOG_SCHEMA,
    LOG_SCHEMA_NAME,
    SCENE_UPDATE_SCHEMA,
    SCENE_UPDATE_SCHEMA_NAME,
    STRING_SCHEMA,
    STRING_SCHEMA_NAME,
    event_log,
    frame_transforms,
    mesh_scene_update,
)
from telemetry.mcap._alarms import TOPIC_ALARMS, alarm_logs
from telemetry.mcap._errors import RecordingFileError
from telemetry.mcap._plots import plot_messages
from telemetry.mcap._schemas import (
    COMMAND_SCHEMA,
    EVENT_SCHEMA,
    FORMAT,
    FORMAT_VERSION,
    METADATA_NAME,
    PLAN_SCHEMA,
    SCHEMA_ENCODING,
    TOPIC_COMMANDS,
    TOPIC_EVENTS,
    TOPIC_PLAN,
    TOPIC_TELEMETRY,
    schema_bytes,
    telemetry_schema,
    urdf_attachment_name,
)
from telemetry.recording import CommandRow, EventRow, PassRecording

__all__ = [
    "TOPIC_ALARMS",
    "TOPIC_EVENT_LOG",
    "TOPIC_ROBOT_DESCRIPTION",
    "TOPIC_ROBOT_MESHES",
    "TOPIC_TF",
    "write_mcap",
]

TOPIC_TF = "/tf"
#: The audit events as ``foxglove.Log`` (Foxglove's Log panel); the live view's ``/events``.
TOPIC_EVENT_LOG = "/events"
TOPIC_ROBOT_DESCRIPTION = "/robot_description"
#: A vendor robot's visual meshes, embedded (telemetry.foxglove.mesh_scene_update).
TOPIC_ROBOT_MESHES = "/robot_meshes"
LIBRARY = f"hikoboshi telemetry.mcap format {FORMAT_VERSION}"
#: Uncompressed bytes per chunk: a few seconds of the pass, so a reader seeks cheaply.
CHUNK_SIZE_BYTES = 1024 * 1024

PathOrStream = str | os.PathLike[str] | IO[bytes]
_Messages = tuple[NDArray[np.int64] | list[int], list[bytes]]


def _dumps(doc: Any) -> bytes:
    return json.dumps(doc, separators=(",", ":"), allow_nan=False).encode()


def _check_recording(recording: PassRecording) -> None:
    frames = recording.frames
    for name, width in frames.layout.arrays.items():
        column = getattr(frames, name)
        if width > 1 and not bool(np.all(np.isfinite(column))):
            row = int(np.argwhere(~np.isfinite(column))[0][0])
            raise RecordingFileError(f"frame column {name} is not finite at row {row}")
    times = {
        "frame generation_time_ns": frames.generation_time_ns.tolist(),
        "command execute_time_ns": [c.execute_time_ns for c in recording.commands],
        "event time_ns": [e.time_ns for e in recording.events],
        "epoch_ns": [recording.epoch_ns],
    }
    for what, values in times.items():
        bad = [v for v in values if not 0 <= v < 2**63]
        if bad:
            raise RecordingFileError(f"{what} {bad[0]} is outside 0 <= t < 2**63 ns")


def _telemetry(recording: PassRecording) -> list[bytes]:
    frames = recording.frames
    columns = {name: getattr(frames, name).tolist() for name in frames.layout.arrays}
    names = list(columns)
    rows = zip(*columns.values(), strict=True)
    return [_dumps(dict(zip(names, row, strict=True))) for row in rows]


def _command(c: CommandRow) -> bytes:
    return _dumps(
        {
            "seq": c.seq,
            "kind": c.kind,
            "execute_time_ns": c.execute_time_ns,
            "payload": dict(c.payload),
            "stage": c.stage,
            "reject_reason": c.reject_reason,
            "stage_times_ns": dict(c.stage_times_ns),
        }
    )


def _event(e: EventRow) -> bytes:
    return _dumps({"time_ns": e.time_ns, "kind": e.kind, "actor": e.actor, "detail": e.detail})


@contextmanager
def _binary_output(target: PathOrStream) -> Iterator[IO[bytes]]:
    if isinstance(target, str | os.PathLike):
        with open(target, "wb") as stream:
            yield stream
    else:
        yield target


def _metadata(recording: PassRecording) -> dict[str, str]:
    # the alarms only where there are some: a recording without keeps the bytes of before
    alarms = {}
    if recording.alarms:
        alarms = {
            "alarms": str(len(recording.alarms)),
            "alarms_json": json.dumps(
                [a.model_dump(mode="json") for a in recording.alarms], allow_nan=False
            ),
        }
    return {
        "format": FORMAT,
        "format_version": str(FORMAT_VERSION),
        "name": recording.name,
        "epoch_ns": str(recording.epoch_ns),
        "meta_json": json.dumps(dict(recording.meta), allow_nan=False),
        "frames": str(len(recording.frames)),
        # numpy's fixed string width is part of the array's bytes; JSON does not carry it.
        "acs_mode_dtype": recording.frames.acs_mode.dtype.str,
        "commands": str(len(recording.commands)),
        "events": str(len(recording.events)),
        "urdf_attachment": urdf_attachment_name(recording.plan.robot),
        **alarms,
    }


def write_mcap(
    recording: PassRecording,
    path_or_stream: PathOrStream,
    *,
    model: RobotModel | None = None,
    urdf: str | None = None,
    meshes: Sequence[tuple[MeshVisual, bytes]] = (),
) -> None:
    """Write ``recording`` as one MCAP file (zstd chunks, chunk and message indexes).

    ``model`` (default: :func:`planner.model.default_model`) gives the URDF and the link
    poses of ``/tf``; its joint count must be the frames' (their
    :class:`~telemetry.layout.FrameLayout`, which also gives the telemetry channel's
    schema). ``urdf``: the robot's URDF document, the export of ``model`` (default:
    :func:`planner.urdf.urdf_xml` of ``model`` under the plan's robot's name); attached as
    ``<robot>.urdf``, the recording's plan's robot (:func:`urdf_attachment_name`: ETS-VII's
    ``ets7.urdf``). ``meshes``: a vendor robot's visual meshes with their files' bytes,
    written once on ``/robot_meshes`` as a ``foxglove.SceneUpdate`` (none: no such topic).
    A stream is written from its current position and left open.
    Raises :class:`RecordingFileError` for a recording that JSON cannot carry exactly
    (a non-finite number, a negative time, a payload that is not JSON).
    """
    _check_recording(recording)
    model = model or default_model()
    layout = recording.frames.layout
    if layout.n_joints != model.n_joints:
        raise RecordingFileError(
            f"the recording's frames have {layout.n_joints} joints, the robot model "
            f"{model.n_joints}: write it with its own robot's model"
        )
    if urdf is None:
        urdf = urdf_xml(model, name=recording.plan.robot)
    frames = recording.frames
    gen_ns = frames.generation_time_ns
    try:
        own: dict[str, tuple[dict[str, Any], str, _Messages]] = {
            TOPIC_TELEMETRY: (
                telemetry_schema(layout),
                "onboard",
                (gen_ns, _telemetry(recording)),
            ),
            TOPIC_COMMANDS: (
                COMMAND_SCHEMA,
                "onboard",
                (
                    [c.execute_time_ns for c in recording.commands],
                    [_command(c) for c in recording.commands],
                ),
            ),
            TOPIC_EVENTS: (
                EVENT_SCHEMA,
                "ground",
                ([e.time_ns for e in recording.events], [_event(e) for e in recording.events]),
            ),
            TOPIC_PLAN: (
                PLAN_SCHEMA,
                "onboard",
                ([recording.epoch_ns], [recording.plan.to_json().encode()]),
            ),
        }
        metadata = _metadata(recording)
    except (TypeError, ValueError) as exc:
        raise RecordingFileError(f"recording cannot be written as JSON: {exc}") from exc

    derived: dict[str, tuple[str, dict[str, Any], str, _Messages]] = {
        TOPIC_TF: (
            FRAME_TRANSFORMS_SCHEMA_NAME,
            FRAME_TRANSFORMS_SCHEMA,
            "onboard",
            (
                gen_ns,
                frame_transforms(
                    model, urdf, gen_ns, frames.quat_orbit_from_base_xyzw, frames.joints_rad
                ),
            ),
        ),
    }
    if recording.events:
        derived[TOPIC_EVENT_LOG] = (
            LOG_SCHEMA_NAME,
            LOG_SCHEMA,
            "ground",
            (
                [e.time_ns for e in recording.events],
                [_dumps(event_log(e.time_ns, e.kind, e.actor, e.detail)) for e in recording.events],
            ),
        )
    if recording.alarms:
        alarm_ns, logs = alarm_logs(recording.alarms, frames, recording.epoch_ns)
        derived[TOPIC_ALARMS] = (
            LOG_SCHEMA_NAME,
            LOG_SCHEMA,
            "onboard",
            (alarm_ns, [_dumps(m) for m in logs]),
        )
    for topic, (schema, log_ns, data) in plot_messages(
        frames, recording.t_s(), recording.plan, recording.epoch_ns
    ).items():
        derived[topic] = (schema["title"], schema, "onboard", (log_ns, data))

    all_times = [int(t) for _, _, (times, _) in own.values() for t in times] + [
        int(t) for _, _, _, (times, _) in derived.values() for t in times
    ]
    start_ns = min(all_times)
    derived[TOPIC_ROBOT_DESCRIPTION] = (
        STRING_SCHEMA_NAME,
        STRING_SCHEMA,
        "first log time of the file",
        ([start_ns], [_dumps({"data": urdf})]),
    )
    if meshes:
        derived[TOPIC_ROBOT_MESHES] = (
            SCENE_UPDATE_SCHEMA_NAME,
            SCENE_UPDATE_SCHEMA,
            "first log time of the file",
            ([start_ns], [_dumps(mesh_scene_update(model, meshes, start_ns))]),
        )

    with _binary_output(path_or_stream) as stream:
        writer = Writer(
            stream,
            chunk_size=CHUNK_SIZE_BYTES,
            compression=CompressionType.ZSTD,
            index_types=IndexType.ALL,
        )
        writer.start(profile="", library=LIBRARY)

        # Our channels' messages first, then the derived ones, each run in log-time order:
        # chunks then hold one group or the other, and a reader of our channels (which
        # filters chunks by the channels they index) skips every derived chunk. The two
        # runs overlap in time, which MCAP allows; Foxglove merges them by log time.
        def add(topic: str, name: str, schema: Mapping[str, Any], clock: str, m: _Messages) -> None:
            schema_id = writer.register_schema(name, SCHEMA_ENCODING, schema_bytes(dict(schema)))
            channel_id = writer.register_channel(
                topic, "json", schema_id, metadata={"clock": clock}
            )
            times, data = m
            for k, (t, d) in enumerate(zip(np.asarray(times).tolist(), data, strict=True)):
                queue.append((t, channel_id, k, d))

        def write_queue() -> None:
            queue.sort(key=lambda item: (item[0], item[1], item[2]))
            for log_ns, channel_id, k, data in queue:
                # sequence: the row within its channel, so the reader restores each
                # channel's own order (log times of different rows may tie or run backwards).
                writer.add_message(
                    channel_id, log_time=log_ns, data=data, publish_time=log_ns, sequence=k
                )
            queue.clear()
            # End the chunk: the next group starts a fresh one. (mcap's flush/finish lack types.)
            writer.flush()  # type: ignore[no-untyped-call]

        queue: list[tuple[int, int, int, bytes]] = []
        for topic, (schema, clock, m) in own.items():
            add(topic, schema["title"], schema, clock, m)
        write_queue()
        for topic, (name, schema, clock, m) in derived.items():
            add(topic, name, schema, clock, m)
        write_queue()
        writer.add_attachment(
            create_time=0,
            log_time=start_ns,
            name=urdf_attachment_name(recording.plan.robot),
            media_type="application/xml",
            data=urdf.encode(),
        )
        writer.add_metadata(METADATA_NAME, metadata)
        writer.finish()  # type: ignore[no-untyped-call]
