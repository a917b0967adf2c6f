"""Telemetry storage: idempotent ingest, gaps, raw ranges, decimation against NumPy."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from sqlalchemy import Engine, func, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from server.storage import repository as repo
from server.storage.db import session_factory
from server.storage.errors import InvalidArgument, NotFound
from server.storage.models import (
    BUCKET_FIELDS,
    PassRecord,
    TelemetryFrameRecord,
)
from telemetry.wire import TelemetryFrame
from tests.server.storage.factories import (
    FRAME_PERIOD_NS,
    RECEIVED_NS,
    T0_NS,
    make_frame,
    make_frames,
    store_pass,
)

NO_PASS = "00000000-0000-0000-0000-000000000000"


def _new_pass(session: Session) -> str:
    return store_pass(session, los_time_ns=1).id


def _ingest(session: Session, pass_id: str, frames: list[TelemetryFrame]) -> repo.IngestResult:
    return repo.ingest_frames(
        session=session, pass_id=pass_id, frames=frames, reception_time_ns=RECEIVED_NS
    )


def _stored(session: Session) -> int:
    return session.scalar(select(func.count()).select_from(TelemetryFrameRecord)) or 0


def test_every_frame_value_round_trips(engine: Engine) -> None:
    frames = make_frames(range(30))
    with session_factory(engine)() as session:
        pass_id = _new_pass(session)
        assert _ingest(session, pass_id, frames) == repo.IngestResult(inserted=30, duplicates=0)
        session.commit()
    with session_factory(engine)() as session:
        rows = session.scalars(
            select(TelemetryFrameRecord).order_by(TelemetryFrameRecord.seq)
        ).all()
        assert len(rows) == 30
        for frame, row in zip(frames, rows, strict=True):
            assert row.pass_id == pass_id
            assert (row.seq, row.generation_time_ns) == (frame.seq, frame.generation_time_ns)
            assert row.reception_time_ns == RECEIVED_NS
            # Doubles round-trip exactly on both backends.
            assert [row.j1, row.j2, row.j3, row.j4, row.j5, row.j6] == frame.joints_rad
            assert [row.t1, row.t2, row.t3, row.t4, row.t5, row.t6] == frame.joint_targets_rad
            assert [row.qx, row.qy, row.qz, row.qw] == frame.quat_orbit_from_base_xyzw
            assert [row.wx, row.wy, row.wz] == frame.omega_base_in_base_radps
            assert [row.ws1, row.ws2, row.ws3] == frame.wheel_speeds_radps
            assert [row.hw1, row.hw2, row.hw3] == frame.wheel_momentum_nms
            assert row.acs_mode == frame.acs_mode.value
            assert [row.tqx, row.tqy, row.tqz, row.tqw] == frame.acs_target_quat_xyzw
            assert row.acs_feedforward is frame.acs_feedforward
            assert row.buffer_queued == frame.buffer.queued
            assert row.buffer_next_execute_time_ns == frame.buffer.next_execute_time_ns
            assert row.buffer_last_executed_seq == frame.buffer.last_executed_seq


def test_ingest_is_idempotent(session: Session) -> None:
    pass_id = _new_pass(session)
    frames = make_frames(range(100))
    assert _ingest(session, pass_id, frames) == repo.IngestResult(inserted=100, duplicates=0)
    session.commit()
    assert _ingest(session, pass_id, frames) == repo.IngestResult(inserted=0, duplicates=100)
    session.commit()
    assert _stored(session) == 100
    # One frame at a time, as a live link may deliver them.
    assert _ingest(session, pass_id, frames[7:8]) == repo.IngestResult(inserted=0, duplicates=1)
    assert _ingest(session, pass_id, make_frames([100])).inserted == 1


def test_overlapping_batches_keep_the_first_copy(session: Session) -> None:
    pass_id = _new_pass(session)
    assert _ingest(session, pass_id, make_frames(range(0, 60))).inserted == 60
    # A resend of 40..59 (with other values: the first copy must stand) plus new 60..99,
    # both in the same transaction as the first batch.
    resend = make_frames(range(40, 100), seed=1)
    assert _ingest(session, pass_id, resend) == repo.IngestResult(inserted=40, duplicates=20)
    # A frame repeated inside one batch counts once.
    twice = make_frames([100, 101, 100])
    assert _ingest(session, pass_id, twice) == repo.IngestResult(inserted=2, duplicates=1)
    session.commit()
    assert repo.frame_seqs(session=session, pass_id=pass_id) == list(range(102))
    assert repo.count_frames(session=session, pass_id=pass_id) == 102
    j1_of_45 = session.scalar(select(TelemetryFrameRecord.j1).where(TelemetryFrameRecord.seq == 45))
    assert j1_of_45 == make_frames(range(0, 60))[45].joints_rad[0]


def test_several_messages_in_one_write_keep_each_its_reception_time(engine: Engine) -> None:
    frames = make_frames(range(30))
    with session_factory(engine)() as session:
        pass_id = _new_pass(session)
        assert repo.ingest_frames(
            session=session, pass_id=pass_id, frames=frames[5:10], reception_time_ns=7
        ) == repo.IngestResult(inserted=5, duplicates=0)
        messages = [(frames[:10], RECEIVED_NS), (frames[10:30], RECEIVED_NS + 1)]
        result = repo.ingest_messages(session=session, pass_id=pass_id, messages=messages)
        assert result == repo.IngestResult(inserted=25, duplicates=5)
        session.commit()
    with session_factory(engine)() as session:
        rows = session.execute(
            select(TelemetryFrameRecord.seq, TelemetryFrameRecord.reception_time_ns).order_by(
                TelemetryFrameRecord.seq
            )
        ).all()
    expected = [(s, 7 if 5 <= s < 10 else RECEIVED_NS + (s >= 10)) for s in range(30)]
    assert [tuple(r) for r in rows] == expected


def test_frames_of_different_passes_do_not_collide(session: Session) -> None:
    a, b = _new_pass(session), _new_pass(session)
    frames = make_frames(range(10))
    assert _ingest(session, a, frames).inserted == 10
    assert _ingest(session, b, frames).inserted == 10
    assert repo.count_frames(session=session, pass_id=a) == 10


def test_empty_batch_stores_nothing(session: Session) -> None:
    pass_id = _new_pass(session)
    assert _ingest(session, pass_id, []) == repo.IngestResult(inserted=0, duplicates=0)


def test_a_batch_for_a_missing_pass_writes_nothing(engine: Engine) -> None:
    with session_factory(engine)() as session:
        with pytest.raises(NotFound, match=NO_PASS):
            _ingest(session, NO_PASS, make_frames(range(10)))
        session.rollback()
        assert _stored(session) == 0


def test_a_batch_failing_half_way_leaves_nothing_half_written(engine: Engine) -> None:
    factory = session_factory(engine)
    with factory() as session:
        kept = _new_pass(session)
        _ingest(session, kept, make_frames(range(5)))
        session.commit()
    good = make_frames(range(200))
    # Frame 100 breaks a NOT NULL column (built past validation, as a bug would).
    broken = TelemetryFrame.model_construct(**{**dict(good[100]), "joints_rad": [None] * 6})
    with factory() as session:
        pass_id = _new_pass(session)  # in the same transaction as the failing batch
        with pytest.raises(IntegrityError):
            _ingest(session, pass_id, [*good[:100], broken, *good[101:]])
        if engine.dialect.name == "sqlite":
            # executemany stopped at frame 100: the first 100 are written, until rollback
            # (PostgreSQL's COPY fails into the stage, its transaction already aborted).
            assert _stored(session) == 5 + 100
        session.rollback()
    with factory() as session:
        assert _stored(session) == 5  # only the committed batch of the other pass
        assert session.scalar(select(func.count()).select_from(PassRecord)) == 1


def test_missing_seqs_finds_every_gap(session: Session) -> None:
    pass_id = _new_pass(session)
    assert repo.missing_seqs(session=session, pass_id=pass_id, up_to_seq=9) == [(0, 9)]
    present = [2, 3, 4, 7, 10, 11, 12, 20]
    _ingest(session, pass_id, make_frames(present))
    assert repo.missing_seqs(session=session, pass_id=pass_id, up_to_seq=25) == [
        (0, 1),
        (5, 6),
        (8, 9),
        (13, 19),
        (21, 25),
    ]
    assert repo.missing_seqs(session=session, pass_id=pass_id, up_to_seq=11) == [
        (0, 1),
        (5, 6),
        (8, 9),
    ]
    assert repo.missing_seqs(session=session, pass_id=pass_id, up_to_seq=-1) == []
    _ingest(session, pass_id, make_frames(range(21)))
    assert repo.missing_seqs(session=session, pass_id=pass_id, up_to_seq=20) == []


def test_missing_seqs_agrees_with_a_set_difference(session: Session) -> None:
    rng = np.random.default_rng(7)
    present = sorted(int(s) for s in np.flatnonzero(rng.random(2000) < 0.9))
    pass_id = _new_pass(session)
    _ingest(session, pass_id, make_frames(present))
    up_to = 2050
    gaps = repo.missing_seqs(session=session, pass_id=pass_id, up_to_seq=up_to)
    expanded = [s for lo, hi in gaps for s in range(lo, hi + 1)]
    assert expanded == sorted(set(range(up_to + 1)) - set(present))
    assert all(hi >= lo for lo, hi in gaps)
    assert all(b[0] > a[1] + 1 for a, b in itertools.pairwise(gaps))  # maximal ranges


def test_telemetry_range_gives_rows_in_time_order(session: Session) -> None:
    pass_id = _new_pass(session)
    frames = make_frames(range(50))
    _ingest(session, pass_id, frames[25:])
    _ingest(session, pass_id, frames[:25])
    t0, t1 = T0_NS + 10 * FRAME_PERIOD_NS, T0_NS + 20 * FRAME_PERIOD_NS
    rows = repo.telemetry_range(
        session=session, pass_id=pass_id, t0_ns=t0, t1_ns=t1, fields=["wz", "acs_mode"]
    )
    assert [r.seq for r in rows] == list(range(10, 20))  # [t0, t1): frame 20 is out
    assert [r.wz for r in rows] == [f.omega_base_in_base_radps[2] for f in frames[10:20]]
    assert [r.acs_mode for r in rows] == [f.acs_mode.value for f in frames[10:20]]
    assert [r.generation_time_ns for r in rows] == [f.generation_time_ns for f in frames[10:20]]
    page = repo.telemetry_range(
        session=session, pass_id=pass_id, t0_ns=t0, t1_ns=t1, fields=["wz"], limit=4
    )
    assert [r.seq for r in page] == [10, 11, 12, 13]  # the first of the range, in order


def _numpy_buckets(
    frames: list[TelemetryFrame], t0: int, t1: int, n: int, fields: list[str]
) -> dict[int, tuple[int, dict[str, tuple[float, float, float]]]]:
    """The reference: bucket index -> (count, field -> (min, max, mean)), in NumPy."""
    gen = np.array([f.generation_time_ns for f in frames], dtype=np.int64)
    values = {
        "j1": np.array([f.joints_rad[0] for f in frames]),
        "t6": np.array([f.joint_targets_rad[5] for f in frames]),
        "qw": np.array([f.quat_orbit_from_base_xyzw[3] for f in frames]),
        "wy": np.array([f.omega_base_in_base_radps[1] for f in frames]),
        "hw3": np.array([f.wheel_momentum_nms[2] for f in frames]),
        "buffer_queued": np.array([f.buffer.queued for f in frames], dtype=np.float64),
    }
    width = -(-(t1 - t0) // n)
    inside = (gen >= t0) & (gen < t1)
    index = (gen[inside] - t0) // width
    out = {}
    for k in np.unique(index):
        sel = index == k
        out[int(k)] = (
            int(sel.sum()),
            {
                f: (
                    float(values[f][inside][sel].min()),
                    float(values[f][inside][sel].max()),
                    float(values[f][inside][sel].mean()),
                )
                for f in fields
            },
        )
    return out


def test_buckets_match_numpy(session: Session) -> None:
    rng = np.random.default_rng(3)
    # 20 minutes at 10 Hz with an outage (frames 3000..3599 never arrived).
    seqs = [s for s in range(12_000) if not 3000 <= s < 3600]
    frames = [make_frame(s, rng) for s in seqs]
    pass_id = _new_pass(session)
    for start in range(0, len(frames), 500):
        _ingest(session, pass_id, frames[start : start + 500])
    fields = ["j1", "t6", "qw", "wy", "hw3", "buffer_queued"]
    # A window that does not start on a frame and whose width does not divide evenly.
    t0 = T0_NS + 123_456_789
    t1 = T0_NS + 1_150 * 10**9 + 1
    n = 487
    got = repo.telemetry_buckets(
        session=session, pass_id=pass_id, t0_ns=t0, t1_ns=t1, fields=fields, buckets=n
    )
    expected = _numpy_buckets(frames, t0, t1, n, fields)
    width = -(-(t1 - t0) // n)
    assert [b.t_start_ns for b in got] == [t0 + k * width for k in sorted(expected)]
    assert len(got) < n  # the outage's buckets are empty and left out
    for bucket in got:
        count, stats = expected[(bucket.t_start_ns - t0) // width]
        assert bucket.count == count
        for f in fields:
            lo, hi, mean = stats[f]
            assert bucket.min[f] == lo and bucket.max[f] == hi  # exact: picked, not computed
            # Summation order differs between the databases and NumPy: a few ulp of the
            # sum of ~24 values of order 1.
            assert bucket.mean[f] == pytest.approx(mean, rel=1e-12, abs=1e-14)
    assert sum(b.count for b in got) == sum(c for c, _ in expected.values())


def test_one_bucket_is_the_whole_window(session: Session) -> None:
    pass_id = _new_pass(session)
    frames = make_frames(range(40))
    _ingest(session, pass_id, frames)
    (only,) = repo.telemetry_buckets(
        session=session,
        pass_id=pass_id,
        t0_ns=T0_NS,
        t1_ns=T0_NS + 4 * 10**9,
        fields=["ws2"],
        buckets=1,
    )
    ws2 = [f.wheel_speeds_radps[1] for f in frames]
    assert (only.t_start_ns, only.count) == (T0_NS, 40)
    assert (only.min["ws2"], only.max["ws2"]) == (min(ws2), max(ws2))


@pytest.mark.parametrize(
    "fields",
    [
        ["j1; DROP TABLE telemetry_frames"],
        ["pass_id"],
        ["acs_mode"],  # a string: no min/max/mean
        [],
        ["j1", "j1"],
    ],
)
def test_bucket_fields_are_whitelisted(session: Session, fields: list[str]) -> None:
    pass_id = _new_pass(session)
    with pytest.raises(InvalidArgument):
        repo.telemetry_buckets(
            session=session, pass_id=pass_id, t0_ns=0, t1_ns=10, fields=fields, buckets=1
        )


def test_range_arguments_are_checked(session: Session) -> None:
    pass_id = _new_pass(session)
    with pytest.raises(InvalidArgument, match="not one of"):
        repo.telemetry_range(
            session=session, pass_id=pass_id, t0_ns=0, t1_ns=1, fields=["seq) UNION SELECT"]
        )
    with pytest.raises(InvalidArgument, match="not the string"):
        repo.telemetry_range(session=session, pass_id=pass_id, t0_ns=0, t1_ns=1, fields="j1")
    with pytest.raises(InvalidArgument, match="empty or reversed"):
        repo.telemetry_range(session=session, pass_id=pass_id, t0_ns=5, t1_ns=5, fields=["j1"])
    with pytest.raises(InvalidArgument, match="buckets"):
        repo.telemetry_buckets(
            session=session, pass_id=pass_id, t0_ns=0, t1_ns=5, fields=["j1"], buckets=0
        )
    with pytest.raises(NotFound):
        repo.telemetry_range(session=session, pass_id=NO_PASS, t0_ns=0, t1_ns=1, fields=["j1"])
    assert set(BUCKET_FIELDS) >= {"j1", "hw3", "tqw", "buffer_queued"}
