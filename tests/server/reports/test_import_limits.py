"""Import is bounded before anything is decompressed: a chunk that holds (or whose zstd
frame holds) more than 64 MiB, or chunks that hold more than the per-file limit together,
are refused with 422 ``invalid_recording``; memory stays small and nothing is stored. On
SQLite and PostgreSQL (``session`` from tests/server/conftest.py).

The bombs are a real recording whose first chunk record is replaced, at the same length
(MCAP allows padding in a record), by 1 GiB of zeros compressed with zstd: about 40 KB,
made streaming, so no test holds the gigabyte."""

from __future__ import annotations

import io
import struct
import subprocess
import sys
from pathlib import Path

import pytest
import zstandard
from fastapi.testclient import TestClient
from sqlalchemy.orm import Session

from server.api.errors import status_of
from server.services.imports import InvalidRecording, import_mcap
from telemetry.mcap import RecordingFileError, read_mcap
from tests.support.api import OPERATOR
from tests.support.archive import row_counts

GIB = 2**30
MIB = 2**20
_MAGIC_LEN = 8
_CHUNK = 0x06


def _zeros_frame(size: int, *, size_in_header: bool) -> bytes:
    out = io.BytesIO()
    cctx = zstandard.ZstdCompressor(level=3)
    with cctx.stream_writer(out, size=size if size_in_header else -1, closefd=False) as w:
        block = bytes(MIB)
        for _ in range(size // MIB):
            w.write(block)
    return out.getvalue()


def _first_chunk(data: bytes) -> tuple[int, int]:
    """(offset, body length) of the file's first chunk record."""
    pos = _MAGIC_LEN
    while True:
        opcode = data[pos]
        (length,) = struct.unpack_from("<Q", data, pos + 1)
        if opcode == _CHUNK:
            return pos, length
        pos += 9 + length


def bomb(mcap: bytes, frame: bytes, declared: int) -> bytes:
    """``mcap`` with its first chunk replaced by ``frame`` declaring ``declared`` bytes."""
    at, length = _first_chunk(mcap)
    start, end = struct.unpack_from("<QQ", mcap, at + 9)
    body = struct.pack("<QQQI", start, end, declared, 0)  # crc 0: not checked
    body += struct.pack("<I", 4) + b"zstd" + struct.pack("<Q", len(frame)) + frame
    assert len(body) <= length, "the recording's first chunk is too small to hold the bomb"
    body += bytes(length - len(body))
    return mcap[: at + 9] + body + mcap[at + 9 + length :]


@pytest.fixture(scope="module")
def frames() -> dict[str, bytes]:
    return {
        "sized": _zeros_frame(GIB, size_in_header=True),
        "unsized": _zeros_frame(GIB, size_in_header=False),
    }


@pytest.fixture(scope="module")
def bombs(short_mcap: bytes, frames: dict[str, bytes]) -> dict[str, bytes]:
    return {
        # declares 1 GiB and holds it: over the per-chunk limit
        "declared": bomb(short_mcap, frames["sized"], GIB),
        # declares 1 MiB, its zstd frame says 1 GiB: the library would allocate the frame's
        "frame_size": bomb(short_mcap, frames["sized"], MIB),
        # declares 1 MiB, its frame does not say: decompression stops at the declared size
        "unsized": bomb(short_mcap, frames["unsized"], MIB),
    }


@pytest.mark.parametrize(
    ("case", "reason"),
    [
        ("declared", "holds 1024.0 MiB uncompressed, over the limit of 64.0 MiB per chunk"),
        ("frame_size", "declares 1048576 bytes uncompressed, its zstd data 1073741824 bytes"),
        ("unsized", "damaged or truncated MCAP file"),
    ],
)
def test_a_decompression_bomb_is_refused_and_nothing_is_stored(
    session: Session, bombs: dict[str, bytes], case: str, reason: str
) -> None:
    data = bombs[case]
    assert len(data) < 2 * MIB
    before = row_counts(session)
    with pytest.raises(InvalidRecording) as info:
        import_mcap(session, data, "otto", source="upload")
    assert status_of(info.value) == 422 and info.value.code == "invalid_recording"
    assert reason in info.value.message
    session.rollback()
    assert row_counts(session) == before


def test_an_uploaded_bomb_gets_the_import_error_shape(
    client: TestClient, bombs: dict[str, bytes]
) -> None:
    response = client.post("/api/passes/import", content=bombs["declared"], headers=OPERATOR)
    assert response.status_code == 422, response.text
    error = response.json()["error"]
    assert error["code"] == "invalid_recording" and "per chunk" in error["message"]


def test_chunks_over_the_per_file_limit_are_refused_before_decompression(
    session: Session, short_mcap: bytes
) -> None:
    read_mcap(io.BytesIO(short_mcap))  # within the default limits
    with pytest.raises(InvalidRecording, match=r"the chunks hold more than 0\.0 MiB uncompressed"):
        import_mcap(session, short_mcap, "otto", source="upload", max_uncompressed_bytes=1000)
    with pytest.raises(RecordingFileError, match=r"over the limit of 0\.0 MiB per chunk"):
        read_mcap(io.BytesIO(short_mcap), max_chunk_bytes=1000)
    session.rollback()
    assert set(row_counts(session).values()) == {0}


_MEASURE = """
import resource, sys
from telemetry.mcap import RecordingFileError, read_mcap
data = open(sys.argv[1], "rb").read()
before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
try:
    read_mcap(__import__("io").BytesIO(data))
except RecordingFileError as exc:
    print("refused:", exc)
after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print("peak_kib", after - before)
"""


@pytest.mark.parametrize("case", ["declared", "frame_size", "unsized"])
def test_peak_memory_stays_small(bombs: dict[str, bytes], tmp_path: Path, case: str) -> None:
    """In a fresh process: the peak resident size grows by far less than the gigabyte
    (before the bound, the tester saw +1.85 GB)."""
    path = tmp_path / f"{case}.mcap"
    path.write_bytes(bombs[case])
    done = subprocess.run(
        [sys.executable, "-c", _MEASURE, str(path)],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
        cwd=Path(__file__).resolve().parents[3],
    )
    lines = done.stdout.splitlines()
    assert lines[0].startswith("refused:"), done.stdout + done.stderr
    peak_kib = int(lines[-1].split()[1])
    assert peak_kib < 100 * 1024, f"peak grew by {peak_kib / 1024:.0f} MiB"
