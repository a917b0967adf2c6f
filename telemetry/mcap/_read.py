"""MCAP import: the exact :class:`~telemetry.recording.PassRecording` that was exported.

Everything is checked before anything is built: the file is read whole, then its record
structure before anything is decompressed (every top-level record inside the file, each
chunk's declared uncompressed size within :data:`MAX_CHUNK_BYTES` and all of them together
within the caller's limit, a zstd frame's own content size equal to its chunk's, the
summary and its indexes pointing at those records), its summary, our metadata record, each
required channel and its schema, then every message of our channels against its schema,
then the counts and per-channel sequences. Any failure raises
:class:`~telemetry.mcap.RecordingFileError`; a partial recording is never returned.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import struct
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import IO, Any

import numpy as np
import zstandard
from mcap.opcode import Opcode
from mcap.reader import McapReader, make_reader
from mcap.records import Channel, Schema
from mcap.summary import Summary
from pydantic import ValidationError

from planner.errors import InvalidInput
from planner.plan import Plan
from telemetry.alarm import AlarmPublic
from telemetry.layout import DEFAULT_LAYOUT, FrameLayout
from telemetry.mcap._errors import RecordingFileError
from telemetry.mcap._jsonschema import SchemaViolation, Validator
from telemetry.mcap._schemas import (
    FORMAT,
    FORMAT_VERSION,
    METADATA_NAME,
    OWN_SCHEMAS,
    PLAN_SCHEMA_BEFORE_FLIGHT_RULES,
    PLAN_SCHEMA_BEFORE_ROBOTS,
    SCHEMA_ENCODING,
    TOPIC_COMMANDS,
    TOPIC_EVENTS,
    TOPIC_PLAN,
    TOPIC_TELEMETRY,
    URDF_ATTACHMENT,
    layout_of_telemetry_schema,
    validators,
)
from telemetry.recording import CommandRow, EventRow, FrameArrays, PassRecording

__all__ = ["MAX_CHUNK_BYTES", "MAX_UNCOMPRESSED_BYTES", "read_mcap", "read_urdf"]

_MAGIC = b"\x89MCAP0\r\n"
#: The most one chunk may hold uncompressed. The writer's chunks are 1 MiB, or one message
#: when a message is larger (the plan, a few MB).
MAX_CHUNK_BYTES = 64 * 2**20
#: The most all the chunks of a file may hold uncompressed, unless the caller says otherwise
#: (8 x the ground's default upload limit; recordings compress about 4:1: the 20-minute
#: demo pass is 14 MB, 59 MB uncompressed).
MAX_UNCOMPRESSED_BYTES = 2 * 2**30
_VALIDATORS = {DEFAULT_LAYOUT: validators()}
_INT_COLUMNS = {"seq", "generation_time_ns", "reception_time_ns"} | {
    n for n in DEFAULT_LAYOUT.arrays if n.startswith("buffer_")
}


def _validators(layout: FrameLayout) -> dict[str, Validator]:
    if layout not in _VALIDATORS:
        _VALIDATORS[layout] = validators(layout)
    return _VALIDATORS[layout]


def _read_bytes(source: str | os.PathLike[str] | IO[bytes]) -> bytes:
    if isinstance(source, str | os.PathLike):
        with open(source, "rb") as f:
            return f.read()
    return source.read()


@dataclass
class _Layout:
    """Where the file's top-level records start, and which of them are chunks."""

    records: set[int] = field(default_factory=set)
    chunks: set[int] = field(default_factory=set)
    uncompressed: int = 0


def _damaged(detail: str) -> RecordingFileError:
    return RecordingFileError(f"damaged or truncated MCAP file: {detail}")


def _mib(n: int) -> str:
    return f"{n / 2**20:.1f} MiB"


def _check_chunk(body: memoryview, at: int, max_chunk: int) -> int:
    """The chunk record's declared uncompressed size, once it is known that decompressing
    it (as the mcap library does) cannot yield more: within ``max_chunk``, zstd or none,
    the zstd frame's content size the declared one or unknown (the library then passes the
    declared size as the most it may produce)."""
    if len(body) < 32:
        raise _damaged(f"chunk at byte {at} is truncated")
    (declared,) = struct.unpack_from("<Q", body, 16)
    (name_len,) = struct.unpack_from("<I", body, 28)
    if 32 + name_len + 8 > len(body):
        raise _damaged(f"chunk at byte {at} is truncated")
    compression = bytes(body[32 : 32 + name_len]).decode("utf-8", "replace")
    (data_len,) = struct.unpack_from("<Q", body, 32 + name_len)
    start = 40 + name_len
    if start + data_len > len(body):
        raise _damaged(f"chunk at byte {at} is truncated")
    if declared > max_chunk:
        raise RecordingFileError(
            f"chunk at byte {at} holds {_mib(declared)} uncompressed, over the limit of "
            f"{_mib(max_chunk)} per chunk"
        )
    if compression == "zstd":
        try:
            size = zstandard.get_frame_parameters(body[start : start + data_len]).content_size
        except zstandard.ZstdError as exc:
            raise _damaged(f"chunk at byte {at}: zstd data: {exc}") from None
        if size not in (declared, zstandard.CONTENTSIZE_UNKNOWN):
            raise RecordingFileError(
                f"chunk at byte {at} declares {declared} bytes uncompressed, its zstd data "
                f"{size} bytes"
            )
    elif compression != "":
        raise RecordingFileError(
            f"chunk at byte {at} is compressed with {compression[:16]!r}: recordings use zstd"
        )
    return int(declared)


def _layout(data: bytes, max_chunk: int, max_total: int) -> _Layout:
    """Walk the top-level records (nothing decompressed) and bound what reading will
    decompress; see :func:`_check_chunk`."""
    if not data.endswith(_MAGIC) or len(data) < 2 * len(_MAGIC):
        raise _damaged("it does not end with the MCAP magic")
    view = memoryview(data)
    end_of_records = len(data) - len(_MAGIC)
    layout = _Layout()
    pos = len(_MAGIC)
    footer: int | None = None
    while pos < end_of_records:
        if pos + 9 > end_of_records:
            raise _damaged(f"record at byte {pos} is cut short")
        opcode = data[pos]
        (length,) = struct.unpack_from("<Q", data, pos + 1)
        end = pos + 9 + length
        if end > end_of_records:
            raise _damaged(f"record at byte {pos} runs past the end of the file")
        layout.records.add(pos)
        if opcode == Opcode.CHUNK:
            layout.chunks.add(pos)
            layout.uncompressed += _check_chunk(view[pos + 9 : end], pos, max_chunk)
            if layout.uncompressed > max_total:
                raise RecordingFileError(
                    f"the chunks hold more than {_mib(max_total)} uncompressed, the limit per file"
                )
        elif opcode == Opcode.FOOTER:
            footer = pos
            break
        pos = end
    if footer is None or end != end_of_records or length < 8:
        raise _damaged("no footer just before its end")
    (summary_start,) = struct.unpack_from("<Q", data, footer + 9)
    if summary_start != 0 and summary_start not in layout.records:
        raise _damaged(f"the footer's summary start {summary_start} is not a record")
    return layout


def _check_indexes(summary: Summary, layout: _Layout) -> None:
    """The summary's indexes point at the records walked: no chunk is read (decompressed)
    twice or from inside another record."""
    starts = [index.chunk_start_offset for index in summary.chunk_indexes]
    if not set(starts) <= layout.chunks or len(set(starts)) != len(starts):
        raise _damaged("the chunk index points at no chunk, or at one chunk twice")
    if not {index.offset for index in summary.metadata_indexes} <= layout.records - layout.chunks:
        raise _damaged("the metadata index points at no metadata record")


def _summary(reader: McapReader) -> Summary:
    summary = reader.get_summary()
    if summary is None:
        raise RecordingFileError("MCAP file has no summary section (truncated or unfinished)")
    return summary


def _metadata(reader: McapReader) -> dict[str, str]:
    for record in reader.iter_metadata():
        if record.name == METADATA_NAME:
            return dict(record.metadata)
    raise RecordingFileError(
        f"not a Hikoboshi pass recording: no {METADATA_NAME!r} metadata record"
    )


def _check_metadata(meta: Mapping[str, str]) -> None:
    if meta.get("format") != FORMAT:
        raise RecordingFileError(f"metadata format {meta.get('format')!r} is not {FORMAT!r}")
    if meta.get("format_version") != str(FORMAT_VERSION):
        raise RecordingFileError(
            f"recording format version {meta.get('format_version')!r} is not {FORMAT_VERSION}"
        )
    for key in ("name", "epoch_ns", "meta_json", "frames", "commands", "events"):
        if key not in meta:
            raise RecordingFileError(f"metadata {METADATA_NAME!r} lacks {key!r}")


def _channels(summary: Summary) -> tuple[dict[str, Channel], FrameLayout]:
    """Our channels by topic, and the frames' layout (from the telemetry schema)."""
    by_topic: dict[str, Channel] = {}
    layout = DEFAULT_LAYOUT
    for channel in summary.channels.values():
        if channel.topic in OWN_SCHEMAS:
            if channel.topic in by_topic:
                raise RecordingFileError(f"channel {channel.topic} appears twice")
            by_topic[channel.topic] = channel
    for topic, want in OWN_SCHEMAS.items():
        if topic not in by_topic:
            raise RecordingFileError(f"required channel {topic} is missing")
        channel = by_topic[topic]
        if channel.message_encoding != "json":
            raise RecordingFileError(
                f"channel {topic} has message encoding {channel.message_encoding!r}, not 'json'"
            )
        schema: Schema | None = summary.schemas.get(channel.schema_id)
        if schema is None or schema.encoding != SCHEMA_ENCODING or schema.name != want["title"]:
            got = None if schema is None else f"{schema.name} ({schema.encoding})"
            raise RecordingFileError(
                f"channel {topic} has schema {got}, expected {want['title']} ({SCHEMA_ENCODING})"
            )
        try:
            written = json.loads(schema.data)
        except ValueError:
            written = None
        if topic == TOPIC_TELEMETRY:
            # Its vectors' lengths are the robot's: any layout's schema, written exactly.
            found = layout_of_telemetry_schema(written)
            same = found is not None
            layout = found or layout
        elif topic == TOPIC_PLAN:
            same = written in (want, PLAN_SCHEMA_BEFORE_FLIGHT_RULES, PLAN_SCHEMA_BEFORE_ROBOTS)
        else:
            same = written == want
        if not same:
            raise RecordingFileError(
                f"channel {topic}: schema {schema.name} differs from this version's"
            )
    return by_topic, layout


def _messages(
    reader: McapReader, channels: dict[str, Channel], layout: FrameLayout
) -> dict[str, list[Any]]:
    """topic -> its decoded, validated messages in the writer's row order."""
    checks = _validators(layout)
    rows: dict[str, dict[int, Any]] = {topic: {} for topic in channels}
    topic_of = {c.id: topic for topic, c in channels.items()}
    for _, channel, message in reader.iter_messages(topics=list(channels), log_time_order=False):
        topic = topic_of.get(channel.id)
        if topic is None:
            continue
        where = f"{topic} message {message.sequence}"
        try:
            doc = json.loads(message.data)
        except RecursionError:
            raise RecordingFileError(f"{where} is not JSON: nested too deep") from None
        except ValueError as exc:
            raise RecordingFileError(f"{where} is not JSON: {exc}") from None
        try:
            checks[topic](doc)
        except SchemaViolation as exc:
            raise RecordingFileError(f"{where} breaks its schema: {exc}") from None
        if message.sequence in rows[topic]:
            raise RecordingFileError(f"{where} appears twice")
        rows[topic][message.sequence] = doc
    out: dict[str, list[Any]] = {}
    for topic, by_seq in rows.items():
        if sorted(by_seq) != list(range(len(by_seq))):
            missing = sorted(set(range(max(by_seq, default=-1) + 1)) - set(by_seq))
            raise RecordingFileError(f"{topic} lacks messages {missing[:5]} (truncated?)")
        out[topic] = [by_seq[k] for k in range(len(by_seq))]
    return out


def _count(meta: Mapping[str, str], key: str, got: int, topic: str) -> None:
    if meta[key] != str(got):
        raise RecordingFileError(f"{topic} holds {got} messages, metadata says {meta[key]}")


def _string_dtype(meta: Mapping[str, str]) -> np.dtype[np.str_]:
    text = meta.get("acs_mode_dtype", "")
    if re.fullmatch(r"[<>]U[0-9]{1,4}", text) is None:
        raise RecordingFileError(f"metadata acs_mode_dtype {text[:32]!r} is not a string dtype")
    return np.dtype(text)


def _frames(
    docs: list[dict[str, Any]], mode_dtype: np.dtype[np.str_], layout: FrameLayout
) -> FrameArrays:
    n = len(docs)
    columns: dict[str, Any] = {}
    for name, width in layout.arrays.items():
        values = [d[name] for d in docs]
        if width > 1:
            columns[name] = np.array(values, dtype=np.float64).reshape(n, width)
        elif name in _INT_COLUMNS:
            columns[name] = np.array(values, dtype=np.int64).reshape(n)
        elif name == "acs_mode":
            natural = np.array(values, dtype=np.str_).reshape(n)
            if natural.dtype.itemsize > mode_dtype.itemsize:
                raise RecordingFileError(
                    f"acs_mode values of {natural.dtype} do not fit its dtype {mode_dtype}"
                )
            columns[name] = natural.astype(mode_dtype)
        else:
            columns[name] = np.array(values, dtype=np.bool_).reshape(n)
    return FrameArrays(**columns)


def _build(
    meta: Mapping[str, str], messages: dict[str, list[Any]], layout: FrameLayout
) -> PassRecording:
    _count(meta, "frames", len(messages[TOPIC_TELEMETRY]), TOPIC_TELEMETRY)
    _count(meta, "commands", len(messages[TOPIC_COMMANDS]), TOPIC_COMMANDS)
    _count(meta, "events", len(messages[TOPIC_EVENTS]), TOPIC_EVENTS)
    if len(messages[TOPIC_PLAN]) != 1:
        raise RecordingFileError(f"{TOPIC_PLAN} holds {len(messages[TOPIC_PLAN])} messages, not 1")
    try:
        plan = Plan.from_dict(messages[TOPIC_PLAN][0])
    except InvalidInput as exc:
        raise RecordingFileError(f"{TOPIC_PLAN}: {exc}") from None
    try:
        epoch_ns = int(meta["epoch_ns"])
        extra = json.loads(meta["meta_json"])
    except ValueError as exc:
        raise RecordingFileError(f"metadata {METADATA_NAME!r}: {exc}") from None
    if not isinstance(extra, dict):
        raise RecordingFileError(f"metadata {METADATA_NAME!r}: meta_json is not an object")
    alarms = _alarms(meta)
    try:
        frames = _frames(messages[TOPIC_TELEMETRY], _string_dtype(meta), layout)
    except (ValueError, OverflowError) as exc:
        raise RecordingFileError(f"{TOPIC_TELEMETRY}: {exc}") from None
    return PassRecording(
        name=meta["name"],
        plan=plan,
        epoch_ns=epoch_ns,
        frames=frames,
        commands=tuple(CommandRow(**d) for d in messages[TOPIC_COMMANDS]),
        events=tuple(EventRow(**d) for d in messages[TOPIC_EVENTS]),
        meta=extra,
        alarms=alarms,
    )


def _alarms(meta: Mapping[str, str]) -> tuple[AlarmPublic, ...]:
    """The alarms of the metadata's ``alarms_json`` (none in a file written before alarms,
    or of a pass without any)."""
    try:
        alarms = json.loads(meta.get("alarms_json", "[]"))
    except ValueError as exc:
        raise RecordingFileError(f"metadata {METADATA_NAME!r}: alarms_json: {exc}") from None
    if not isinstance(alarms, list) or not all(isinstance(a, dict) for a in alarms):
        raise RecordingFileError(
            f"metadata {METADATA_NAME!r}: alarms_json is not a list of objects"
        )
    if "alarms" in meta and meta["alarms"] != str(len(alarms)):
        raise RecordingFileError(
            f"metadata {METADATA_NAME!r} says {meta['alarms']} alarms, alarms_json holds "
            f"{len(alarms)}"
        )
    out = []
    for k, doc in enumerate(alarms):
        try:
            out.append(AlarmPublic.model_validate(doc))
        except ValidationError as exc:
            first = exc.errors()[0]
            where = ".".join(str(p) for p in first["loc"])
            raise RecordingFileError(
                f"metadata {METADATA_NAME!r}: alarms_json: alarm {k}: {where}: {first['msg']}"
            ) from None
    return tuple(out)


def read_mcap(
    path_or_stream: str | os.PathLike[str] | IO[bytes],
    *,
    max_uncompressed_bytes: int = MAX_UNCOMPRESSED_BYTES,
    max_chunk_bytes: int = MAX_CHUNK_BYTES,
) -> PassRecording:
    """The recording that :func:`~telemetry.mcap.write_mcap` wrote (a stream is read from its
    current position to its end). Only our channels are read; the derived Foxglove and plot
    channels are not needed. A file whose chunks declare more than ``max_chunk_bytes`` each
    or ``max_uncompressed_bytes`` together is refused before anything is decompressed.
    Raises :class:`~telemetry.mcap.RecordingFileError`."""
    data = _mcap_bytes(path_or_stream)
    layout = _layout(data, max_chunk_bytes, max_uncompressed_bytes)
    with _damage_is_a_recording_error():
        reader = make_reader(io.BytesIO(data), validate_crcs=True)
        summary = _summary(reader)
        _check_indexes(summary, layout)
        meta = _metadata(reader)
        _check_metadata(meta)
        channels, frame_layout = _channels(summary)
        messages = _messages(reader, channels, frame_layout)
    return _build(meta, messages, frame_layout)


def _mcap_bytes(path_or_stream: str | os.PathLike[str] | IO[bytes]) -> bytes:
    data = _read_bytes(path_or_stream)
    if not data.startswith(_MAGIC):
        raise RecordingFileError(f"not an MCAP file: starts with {data[:8]!r}")
    return data


@contextlib.contextmanager
def _damage_is_a_recording_error() -> Iterator[None]:
    """The mcap library signals damaged input with many types (McapError, struct.error,
    zstd errors, EndOfFile, KeyError, ...), none of them documented as its contract.
    Whatever it raises while parsing, the file is not a readable recording."""
    try:
        yield
    except RecordingFileError:
        raise
    except Exception as exc:
        raise RecordingFileError(
            f"damaged or truncated MCAP file: {type(exc).__name__}: {exc}"
        ) from exc


def read_urdf(path_or_stream: str | os.PathLike[str] | IO[bytes]) -> tuple[str, str]:
    """The robot's URDF attached to a recording: ``(attachment name, document)``. The
    attachment the metadata names (``urdf_attachment``: ``<robot>.urdf``, the recording's
    robot), else ``ets7.urdf`` (recordings written before attachments took their robot's
    name), else the file's only ``.urdf`` attachment. Raises
    :class:`~telemetry.mcap.RecordingFileError` for a file that is not ours or has none."""
    data = _mcap_bytes(path_or_stream)
    with _damage_is_a_recording_error():
        reader = make_reader(io.BytesIO(data), validate_crcs=True)
        meta = _metadata(reader)
        _check_metadata(meta)
        attachments = {a.name: a.data for a in reader.iter_attachments()}
    urdfs = [name for name in attachments if name.endswith(".urdf")]
    only = urdfs if len(urdfs) == 1 else []
    for name in (meta.get("urdf_attachment"), URDF_ATTACHMENT, *only):
        if name is not None and name in attachments:
            try:
                return name, bytes(attachments[name]).decode()
            except UnicodeDecodeError:
                raise RecordingFileError(f"attachment {name!r} is not UTF-8") from None
    raise RecordingFileError(
        f"the recording has no URDF attachment (metadata names "
        f"{meta.get('urdf_attachment')!r}; attachments: {sorted(attachments)})"
    )
