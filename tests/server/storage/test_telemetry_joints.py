"""The archive for any joint count up to MAX_STORED_JOINTS: a 7-joint pass stored and read
back on both backends, ETS-VII's passes unchanged, frames of another robot refused."""

from __future__ import annotations

import numpy as np
import pytest
from sqlalchemy import select
from sqlalchemy.orm import Session

from server.services.recordings import _frames as stored_frame_arrays
from server.storage import repository as repo
from server.storage.errors import InvalidArgument
from server.storage.models import MAX_STORED_JOINTS, PlanRecord, TelemetryFrameRecord
from telemetry.layout import DEFAULT_LAYOUT, FrameLayout
from telemetry.recording import frames_to_arrays
from tests.server.storage.factories import (
    FRAME_PERIOD_NS,
    RECEIVED_NS,
    T0_NS,
    make_frames,
    make_plan,
    store_pass,
)

SEVEN = FrameLayout(7, 3)


def _new_pass(session: Session, n_joints: int, name: str = "p") -> str:
    record = store_pass(session, make_plan(n_joints=n_joints), name=name, los_time_ns=1)
    plan = session.get(PlanRecord, record.plan_id)
    assert plan is not None and plan.n_joints == n_joints
    return record.id


def test_a_seven_joint_stream_is_stored_and_read_back_exactly(session: Session) -> None:
    pass_id = _new_pass(session, 7)
    assert repo.get_pass_layout(session=session, pass_id=pass_id) == SEVEN
    frames = make_frames(range(50), seed=7, layout=SEVEN)
    result = repo.ingest_frames(
        session=session, pass_id=pass_id, frames=frames, reception_time_ns=RECEIVED_NS
    )
    assert result == repo.IngestResult(inserted=50, duplicates=0)
    again = repo.ingest_frames(
        session=session, pass_id=pass_id, frames=frames[:5], reception_time_ns=RECEIVED_NS + 1
    )
    assert again == repo.IngestResult(inserted=0, duplicates=5)
    session.commit()

    # Raw rows of every field of the layout: exactly the frames' rows.
    rows = repo.telemetry_range(
        session=session, pass_id=pass_id, t0_ns=0, t1_ns=2**62, fields=SEVEN.fields
    )
    assert [tuple(r) for r in rows] == SEVEN.rows(frames, RECEIVED_NS)
    assert [r.j7 for r in rows] == [f.joints_rad[6] for f in frames]
    assert [r.t7 for r in rows] == [f.joint_targets_rad[6] for f in frames]
    # joints 8.. stay NULL
    record = session.scalars(select(TelemetryFrameRecord)).first()
    assert record is not None and record.j8 is None and record.t12 is None

    # Decimation of the seventh joint, against NumPy.
    buckets = repo.telemetry_buckets(
        session=session,
        pass_id=pass_id,
        t0_ns=T0_NS,
        t1_ns=T0_NS + 50 * FRAME_PERIOD_NS,
        fields=["j7", "t7"],
        buckets=5,
    )
    j7 = np.array([f.joints_rad[6] for f in frames]).reshape(5, 10)
    assert [b.count for b in buckets] == [10] * 5
    assert [b.min["j7"] for b in buckets] == j7.min(axis=1).tolist()
    assert [b.max["j7"] for b in buckets] == j7.max(axis=1).tolist()
    assert np.allclose([b.mean["j7"] for b in buckets], j7.mean(axis=1), rtol=0, atol=1e-12)

    # The recording reads the columns of the pass's layout, the same arrays as the frames.
    arrays = stored_frame_arrays(session, pass_id)
    assert arrays.layout == SEVEN
    assert SEVEN.arrays_to_frames(arrays) == frames
    assert arrays.reception_time_ns.tolist() == [RECEIVED_NS] * 50


def test_an_imported_seven_joint_recording_is_stored_exactly(session: Session) -> None:
    pass_id = _new_pass(session, 7)
    frames = make_frames(range(20), seed=3, layout=SEVEN)
    arrays = frames_to_arrays(frames, [RECEIVED_NS + k for k in range(20)])
    assert repo.add_frame_arrays(session=session, pass_id=pass_id, frames=arrays) == 20
    session.commit()
    back = stored_frame_arrays(session, pass_id)
    assert SEVEN.arrays_to_rows(back) == SEVEN.arrays_to_rows(arrays)


def test_ets7_passes_keep_six_joints_and_null_beyond(session: Session) -> None:
    pass_id = _new_pass(session, 6)
    frames = make_frames(range(10))
    repo.ingest_frames(
        session=session, pass_id=pass_id, frames=frames, reception_time_ns=RECEIVED_NS
    )
    session.commit()
    assert repo.get_pass_layout(session=session, pass_id=pass_id) == DEFAULT_LAYOUT
    records = session.scalars(select(TelemetryFrameRecord)).all()
    assert len(records) == 10
    assert all(r.j7 is None and r.t7 is None and r.j12 is None for r in records)
    assert [r.j6 for r in sorted(records, key=lambda r: r.seq)] == [f.joints_rad[5] for f in frames]
    with pytest.raises(InvalidArgument, match="'j7' is not one of"):
        repo.telemetry_range(session=session, pass_id=pass_id, t0_ns=0, t1_ns=1, fields=["j7"])
    with pytest.raises(InvalidArgument, match="'t7' is not one of"):
        repo.telemetry_buckets(
            session=session, pass_id=pass_id, t0_ns=0, t1_ns=1, fields=["t7"], buckets=1
        )


def test_frames_of_another_robot_are_refused_and_nothing_is_stored(session: Session) -> None:
    ets7 = _new_pass(session, 6, "ets7")
    seven = _new_pass(session, 7, "seven")
    with pytest.raises(InvalidArgument, match=r"joints_rad has 7 values.*6 joints"):
        repo.ingest_frames(
            session=session,
            pass_id=ets7,
            frames=make_frames(range(3), layout=SEVEN),
            reception_time_ns=RECEIVED_NS,
        )
    with pytest.raises(InvalidArgument, match=r"joints_rad has 6 values.*7 joints"):
        repo.ingest_frames(
            session=session, pass_id=seven, frames=make_frames(range(3)), reception_time_ns=0
        )
    with pytest.raises(InvalidArgument, match=r"6 joints.*7 joints"):
        repo.add_frame_arrays(
            session=session, pass_id=seven, frames=frames_to_arrays(make_frames(range(3)))
        )
    assert repo.count_frames(session=session, pass_id=ets7) == 0
    assert repo.count_frames(session=session, pass_id=seven) == 0


def test_a_plan_of_more_joints_than_the_archive_has_is_refused(session: Session) -> None:
    too_many = make_plan(n_joints=MAX_STORED_JOINTS + 1)
    with pytest.raises(InvalidArgument, match=f"1..{MAX_STORED_JOINTS} joints, not 13"):
        repo.add_plan(session=session, plan=too_many, created_at_ns=0)
    record = repo.add_plan(
        session=session, plan=make_plan(n_joints=MAX_STORED_JOINTS), created_at_ns=0
    )
    assert record.n_joints == MAX_STORED_JOINTS
