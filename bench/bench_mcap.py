"""MCAP export and import of the 20-minute demo pass, against plain baselines.

The pass: the whole demo schedule (``plan_pass``) flown offline through the vehicle, about
12 300 telemetry frames at 10 Hz. Timed, best of REPEAT:

- ``write_mcap`` to memory: our channels (telemetry, plan with prediction, commands,
  events), the Foxglove ``/tf`` transforms of every link, the plot channels, the URDF;
- ``read_mcap`` of that file (every message of our channels parsed and schema-checked);
- baselines in the same run, on the same frames: the telemetry columns as JSON lines
  (``json.dumps`` of one object per frame, then zstd like the MCAP chunks) and as
  ``numpy.savez_compressed`` (binary columns, deflate), each written and read back.

Sizes are of the whole file / payload. No targets are set by an issue; the one stated here
is that a round trip of a pass stays interactive: export and import each < 10 s.
"""

from __future__ import annotations

import io
import json
from typing import Any

import numpy as np
import zstandard
from _common import best_of, emit
from mcap.reader import make_reader

from planner.dynamics import DynamicsWorkspace
from planner.model import default_model
from planner.schedule import plan_pass
from spacecraft.offline import fly_offline
from telemetry.mcap import TOPIC_TELEMETRY, read_mcap, write_mcap
from telemetry.recording import FRAME_ARRAYS, PassRecording

REPEAT = 3


def demo_recording() -> PassRecording:
    model = default_model()
    plan = plan_pass(DynamicsWorkspace(model))
    flight = fly_offline(plan, seed=7)
    return PassRecording.from_frames("demo", plan, flight.epoch_ns, flight.frames)


def own_chunk_bytes(data: bytes) -> int:
    """Bytes of the chunks that hold our channels (telemetry, plan, commands, events): the
    writer puts them apart from the derived Foxglove and plot chunks."""
    summary = make_reader(io.BytesIO(data)).get_summary()
    assert summary is not None
    own = {cid for cid, c in summary.channels.items() if c.topic.startswith("/hikoboshi/")}
    return sum(c.chunk_length for c in summary.chunk_indexes if own & set(c.message_index_offsets))


def main() -> None:
    recording = demo_recording()
    frames = recording.frames
    model = default_model()

    def export() -> bytes:
        buf = io.BytesIO()
        write_mcap(recording, buf, model=model)
        return buf.getvalue()

    mcap_bytes = export()
    write_s = best_of(export, repeat=REPEAT)
    read_s = best_of(lambda: read_mcap(io.BytesIO(mcap_bytes)), repeat=REPEAT)
    back = read_mcap(io.BytesIO(mcap_bytes))
    exact = all(
        getattr(back.frames, n).tobytes() == getattr(frames, n).tobytes() for n in FRAME_ARRAYS
    )

    columns = {name: getattr(frames, name).tolist() for name in FRAME_ARRAYS}

    def jsonl_write() -> bytes:
        names = list(columns)
        rows = zip(*columns.values(), strict=True)
        text = "\n".join(json.dumps(dict(zip(names, r, strict=True))) for r in rows)
        return zstandard.compress(text.encode())

    jsonl = jsonl_write()

    def jsonl_read() -> Any:
        lines = zstandard.decompress(jsonl).decode().split("\n")
        docs = [json.loads(line) for line in lines]
        return {n: np.array([d[n] for d in docs]) for n in FRAME_ARRAYS}

    def npz_write() -> bytes:
        buf = io.BytesIO()
        np.savez_compressed(buf, **{n: getattr(frames, n) for n in FRAME_ARRAYS})
        return buf.getvalue()

    npz = npz_write()

    def npz_read() -> Any:
        with np.load(io.BytesIO(npz)) as data:
            return {n: data[n] for n in FRAME_ARRAYS}

    figures: dict[str, Any] = {
        "frames": len(frames),
        "pass_s": float(recording.t_s()[-1] - recording.t_s()[0]),
        "mcap_write_s": write_s,
        "mcap_read_s": read_s,
        "mcap_bytes": len(mcap_bytes),
        "mcap_own_channel_chunk_bytes": own_chunk_bytes(mcap_bytes),
        "mcap_round_trip_bitwise": exact,
        "mcap_read_topic": TOPIC_TELEMETRY,
        "jsonl_zstd_write_s": best_of(jsonl_write, repeat=REPEAT),
        "jsonl_zstd_read_s": best_of(jsonl_read, repeat=REPEAT),
        "jsonl_zstd_bytes": len(jsonl),
        "npz_write_s": best_of(npz_write, repeat=REPEAT),
        "npz_read_s": best_of(npz_read, repeat=REPEAT),
        "npz_bytes": len(npz),
    }
    figures["mcap_write_vs_jsonl"] = figures["mcap_write_s"] / figures["jsonl_zstd_write_s"]
    figures["mcap_read_vs_jsonl"] = figures["mcap_read_s"] / figures["jsonl_zstd_read_s"]
    emit(
        "mcap",
        figures,
        {
            "export_lt_10s": write_s < 10.0,
            "import_lt_10s": read_s < 10.0,
            "round_trip_bitwise": exact,
        },
    )


if __name__ == "__main__":
    main()
