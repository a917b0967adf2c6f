"""The frame layout: one definition of a frame's values, exact in every direction."""

from __future__ import annotations

import numpy as np
import pytest

from telemetry.layout import DEFAULT_LAYOUT, FrameLayout, FrameLayoutError
from telemetry.recording import FRAME_ARRAYS, FrameArrays, frames_to_arrays
from tests.server.storage.factories import make_frames

#: ETS-VII's columns as the archive has always named and ordered them (models, console).
ETS7_COLUMNS = (
    "seq",
    "generation_time_ns",
    *(f"j{i}" for i in range(1, 7)),
    *(f"t{i}" for i in range(1, 7)),
    *("qx", "qy", "qz", "qw", "wx", "wy", "wz", "ws1", "ws2", "ws3", "hw1", "hw2", "hw3"),
    *("tqx", "tqy", "tqz", "tqw"),
    *("acs_mode", "acs_feedforward", "buffer_queued", "buffer_next_execute_time_ns"),
    *("buffer_last_executed_seq", "reception_time_ns"),
)


def test_the_default_layout_is_ets7s_as_it_always_was() -> None:
    assert FrameLayout(6, 3) == DEFAULT_LAYOUT
    assert DEFAULT_LAYOUT.columns == ETS7_COLUMNS
    assert FRAME_ARRAYS["joints_rad"] == 6 and FRAME_ARRAYS["wheel_speeds_radps"] == 3
    assert DEFAULT_LAYOUT.bucket_fields[-1] == "buffer_queued"
    assert "acs_mode" not in DEFAULT_LAYOUT.bucket_fields


def test_a_seven_joint_layout_names_its_joints_and_keeps_the_rest() -> None:
    layout = FrameLayout(7, 3)
    assert layout.float_fields[:14] == (
        *(f"j{i}" for i in range(1, 8)),
        *(f"t{i}" for i in range(1, 8)),
    )
    assert layout.float_fields[14:] == DEFAULT_LAYOUT.float_fields[12:]
    assert layout.arrays["joints_rad"] == 7 and layout.arrays["joint_targets_rad"] == 7
    assert layout.sources["t7"] == ("joint_targets_rad", 6)
    assert layout.sources["ws3"] == ("wheel_speeds_radps", 2)
    assert layout.sources["acs_mode"] == ("acs_mode", None)
    # wheel momentum is a base-frame vector: three values whatever the wheel count
    assert FrameLayout(6, 4).arrays["wheel_momentum_nms"] == 3
    assert FrameLayout(6, 4).float_fields.count("ws4") == 1


@pytest.mark.parametrize("n_joints", [6, 7])
def test_wire_row_arrays_wire_round_trip_is_exact(n_joints: int) -> None:
    layout = FrameLayout(n_joints, 3)
    frames = make_frames(range(40), seed=n_joints, layout=layout)
    assert len(frames[0].joints_rad) == n_joints
    rows = layout.rows(frames, reception_time_ns=123)
    assert all(len(r) == len(layout.columns) for r in rows)
    assert [layout.frame(r) for r in rows] == frames
    arrays = layout.rows_to_arrays(rows)
    assert arrays.joints_rad.shape == (40, n_joints)
    assert arrays.layout == layout
    assert layout.arrays_to_rows(arrays) == rows
    assert layout.arrays_to_frames(arrays) == frames
    # frames_to_arrays takes the layout from the frames themselves
    direct = frames_to_arrays(frames, [123] * len(frames))
    assert layout.arrays_to_rows(direct) == rows
    # each value lands in its own named column
    k = 17
    assert rows[k][layout.columns.index(f"j{n_joints}")] == frames[k].joints_rad[-1]
    assert rows[k][layout.columns.index("tqw")] == frames[k].acs_target_quat_xyzw[3]
    assert arrays.buffer_next_execute_time_ns[0] == -1  # seq 0: nothing queued
    assert rows[0][layout.columns.index("buffer_next_execute_time_ns")] is None


def test_a_frame_of_another_shape_is_refused_with_the_reason() -> None:
    seven = make_frames(range(3), layout=FrameLayout(7, 3))
    with pytest.raises(FrameLayoutError, match=r"joints_rad has 7 values.*6 joints, 3 wheels.*6"):
        DEFAULT_LAYOUT.row(seven[0], 0)
    with pytest.raises(FrameLayoutError, match="joints_rad has 7 values"):
        DEFAULT_LAYOUT.frames_to_arrays(seven)
    mixed = [*make_frames(range(2)), seven[2]]
    with pytest.raises(FrameLayoutError, match="frame 2: joints_rad"):
        frames_to_arrays(mixed)
    arrays = frames_to_arrays(seven)
    with pytest.raises(FrameLayoutError, match=r"7 joints, 3 wheels.*6 joints, 3 wheels"):
        DEFAULT_LAYOUT.arrays_to_rows(arrays)
    with pytest.raises(FrameLayoutError, match="row of 3 values"):
        DEFAULT_LAYOUT.frame((1, 2, 3))


def test_arrays_whose_columns_disagree_are_refused() -> None:
    arrays = frames_to_arrays(make_frames(range(4), layout=FrameLayout(7, 3)))
    columns = {name: getattr(arrays, name) for name in arrays.layout.arrays}
    columns["joint_targets_rad"] = columns["joint_targets_rad"][:, :6]
    with pytest.raises(
        ValueError, match=r"joint_targets_rad has shape \(4, 6\), expected \(4, 7\)"
    ):
        FrameArrays(**columns)


@pytest.mark.parametrize(("n_joints", "n_wheels"), [(0, 3), (33, 3), (6, 0), (6, 17)])
def test_a_layout_out_of_bounds_is_refused(n_joints: int, n_wheels: int) -> None:
    with pytest.raises(FrameLayoutError, match="outside"):
        FrameLayout(n_joints, n_wheels)


def test_empty_arrays_keep_their_layout() -> None:
    empty = FrameArrays.empty(FrameLayout(7, 3))
    assert len(empty) == 0 and empty.joints_rad.shape == (0, 7)
    assert np.shape(FrameArrays.empty().joints_rad) == (0, 6)
