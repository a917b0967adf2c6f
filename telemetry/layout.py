"""The telemetry frame's layout, defined once: every per-frame value, named and in order.

A :class:`FrameLayout` follows from the robot: its joint count ``n`` and wheel count ``k``
(ETS-VII: 6 and 3, :data:`DEFAULT_LAYOUT`). It names each value of a
:class:`~telemetry.wire.TelemetryFrame` as the archive stores it and converts in both
directions between the three shapes a frame takes:

- the **wire** frame (:class:`~telemetry.wire.TelemetryFrame`, the vectors as lists);
- a flat **row**, a tuple in :attr:`FrameLayout.columns` order::

      seq, generation_time_ns,
      j1..jn            measured joints (rad)
      t1..tn            servo targets (rad)
      qx, qy, qz, qw    quat_orbit_from_base
      wx, wy, wz        omega_base_in_base (rad/s)
      ws1..wsk          wheel speeds relative to the base (rad/s)
      hw1, hw2, hw3     wheel momentum, a base-frame vector (N m s): always 3
      tqx..tqw          the ACS target quaternion
      acs_mode, acs_feedforward, buffer_queued, buffer_next_execute_time_ns,
      buffer_last_executed_seq, reception_time_ns

  (``buffer_next_execute_time_ns`` is None where nothing is queued): what the storage
  inserts and reads back, and what the console's telemetry ``columns`` are;
- :class:`~telemetry.recording.FrameArrays` columns, one row per frame
  (:attr:`FrameLayout.arrays`: column name -> width; ``buffer_next_execute_time_ns`` is -1
  where nothing is queued).

The buffer's ``last_queued_time_ns`` and ``capacity`` are not archived: a frame read back
from a row or arrays has them None. A frame whose vector lengths differ from the layout is
refused with :class:`FrameLayoutError` naming the vector and both lengths.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING, Any

import numpy as np

from telemetry.wire import MAX_JOINTS, MAX_WHEELS, AcsModeName, BufferState, TelemetryFrame

if TYPE_CHECKING:
    from telemetry.recording import FrameArrays

__all__ = [
    "DEFAULT_LAYOUT",
    "MAX_JOINTS",
    "MAX_WHEELS",
    "FrameLayout",
    "FrameLayoutError",
]

Row = tuple[Any, ...]


class FrameLayoutError(ValueError):
    """A frame (or arrays, or a row) that does not have the layout's shape; the text says
    which value and how."""


#: The per-frame scalars after the vectors, in row order (``reception_time_ns`` last).
_SCALARS = (
    "acs_mode",
    "acs_feedforward",
    "buffer_queued",
    "buffer_next_execute_time_ns",
    "buffer_last_executed_seq",
)
#: Fixed-width vectors: wire/array name -> column names.
_QUAT = ("qx", "qy", "qz", "qw")
_OMEGA = ("wx", "wy", "wz")
_MOMENTUM = ("hw1", "hw2", "hw3")
_TARGET_QUAT = ("tqx", "tqy", "tqz", "tqw")
#: The unit of each vector's values.
_VECTOR_UNITS = {
    "joints_rad": "rad",
    "joint_targets_rad": "rad",
    "quat_orbit_from_base_xyzw": "1",
    "omega_base_in_base_radps": "rad/s",
    "wheel_speeds_radps": "rad/s",
    "wheel_momentum_nms": "N m s",
    "acs_target_quat_xyzw": "1",
}


@dataclass(frozen=True)
class FrameLayout:
    """The values of one telemetry frame for a robot of ``n_joints`` joints and
    ``n_wheels`` reaction wheels (see the module doc)."""

    n_joints: int = 6
    n_wheels: int = 3

    def __post_init__(self) -> None:
        for what, value, most in (
            ("n_joints", self.n_joints, MAX_JOINTS),
            ("n_wheels", self.n_wheels, MAX_WHEELS),
        ):
            if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= most:
                raise FrameLayoutError(f"{what} {value!r} is outside 1..{most}")

    def __str__(self) -> str:
        return f"{self.n_joints} joints, {self.n_wheels} wheels"

    # --- names ------------------------------------------------------------------------------

    @cached_property
    def vectors(self) -> tuple[tuple[str, tuple[str, ...]], ...]:
        """``(wire/array name, its column names)`` of every vector, in row order."""
        n, k = self.n_joints, self.n_wheels
        return (
            ("joints_rad", tuple(f"j{i}" for i in range(1, n + 1))),
            ("joint_targets_rad", tuple(f"t{i}" for i in range(1, n + 1))),
            ("quat_orbit_from_base_xyzw", _QUAT),
            ("omega_base_in_base_radps", _OMEGA),
            ("wheel_speeds_radps", tuple(f"ws{i}" for i in range(1, k + 1))),
            ("wheel_momentum_nms", _MOMENTUM),
            ("acs_target_quat_xyzw", _TARGET_QUAT),
        )

    @cached_property
    def float_fields(self) -> tuple[str, ...]:
        """The float columns, in row order (``j1..jn, t1..tn, qx..qw, wx..wz, ws1..wsk,
        hw1..hw3, tqx..tqw``)."""
        return tuple(name for _, names in self.vectors for name in names)

    @cached_property
    def fields(self) -> tuple[str, ...]:
        """Every per-frame value a query may ask for: the floats, the scalars and
        ``reception_time_ns``."""
        return (*self.float_fields, *_SCALARS, "reception_time_ns")

    @cached_property
    def bucket_fields(self) -> tuple[str, ...]:
        """The values that can be decimated (min / max / mean): the numbers."""
        return (*self.float_fields, "buffer_queued")

    @cached_property
    def columns(self) -> tuple[str, ...]:
        """A row's values, in order: ``seq``, ``generation_time_ns`` and :attr:`fields`."""
        return ("seq", "generation_time_ns", *self.fields)

    @cached_property
    def units(self) -> dict[str, str]:
        """Column of :attr:`columns` -> its unit (``"1"``: a quaternion's components; ``""``:
        a count, a sequence number, a mode or a flag)."""
        out = dict.fromkeys(self.columns, "")
        for array, names in self.vectors:
            out.update(dict.fromkeys(names, _VECTOR_UNITS[array]))
        for name in ("generation_time_ns", "buffer_next_execute_time_ns", "reception_time_ns"):
            out[name] = "ns"
        return out

    @cached_property
    def arrays(self) -> dict[str, int]:
        """:class:`~telemetry.recording.FrameArrays` column -> row width (1: one value)."""
        widths = dict(self.vectors)
        return {
            "seq": 1,
            "generation_time_ns": 1,
            "reception_time_ns": 1,
            "joints_rad": len(widths["joints_rad"]),
            "joint_targets_rad": len(widths["joint_targets_rad"]),
            "quat_orbit_from_base_xyzw": 4,
            "omega_base_in_base_radps": 3,
            "wheel_speeds_radps": len(widths["wheel_speeds_radps"]),
            "wheel_momentum_nms": 3,
            "acs_mode": 1,
            "acs_target_quat_xyzw": 4,
            "acs_feedforward": 1,
            "buffer_queued": 1,
            "buffer_next_execute_time_ns": 1,
            "buffer_last_executed_seq": 1,
        }

    @cached_property
    def sources(self) -> dict[str, tuple[str, int | None]]:
        """Row column -> the :class:`FrameArrays` column holding it and its index there
        (None: a width-1 column)."""
        out: dict[str, tuple[str, int | None]] = {}
        for name in self.columns:
            out[name] = (name, None)
        for array, names in self.vectors:
            for index, name in enumerate(names):
                out[name] = (array, index)
        return out

    # --- shapes -----------------------------------------------------------------------------

    @classmethod
    def of_frame(cls, frame: TelemetryFrame) -> FrameLayout:
        """The layout a frame's own vector lengths give."""
        return cls(len(frame.joints_rad), len(frame.wheel_speeds_radps))

    @classmethod
    def of_arrays(cls, frames: FrameArrays) -> FrameLayout:
        """The layout of column arrays (from their joint and wheel-speed widths)."""
        return cls(*_widths(frames))

    def check(self, frame: TelemetryFrame) -> None:
        """Raise :class:`FrameLayoutError` unless every vector of ``frame`` has this
        layout's length."""
        for array, names in self.vectors:
            got = len(getattr(frame, array))
            if got != len(names):
                raise FrameLayoutError(
                    f"frame {frame.seq}: {array} has {got} values, the robot's layout "
                    f"({self}) has {len(names)}"
                )

    def check_arrays(self, frames: FrameArrays) -> None:
        """Raise :class:`FrameLayoutError` unless the arrays have this layout's widths."""
        got = FrameLayout.of_arrays(frames)
        if got != self:
            raise FrameLayoutError(f"frame arrays of {got} do not fit the layout ({self})")

    # --- wire <-> row -----------------------------------------------------------------------

    def row(self, frame: TelemetryFrame, reception_time_ns: int) -> Row:
        """``frame`` as a row of :attr:`columns` (checked against the layout)."""
        self.check(frame)
        buffer = frame.buffer
        return (
            frame.seq,
            frame.generation_time_ns,
            *frame.joints_rad,
            *frame.joint_targets_rad,
            *frame.quat_orbit_from_base_xyzw,
            *frame.omega_base_in_base_radps,
            *frame.wheel_speeds_radps,
            *frame.wheel_momentum_nms,
            *frame.acs_target_quat_xyzw,
            frame.acs_mode.value,
            frame.acs_feedforward,
            buffer.queued,
            buffer.next_execute_time_ns,
            buffer.last_executed_seq,
            reception_time_ns,
        )

    def rows(self, frames: Iterable[TelemetryFrame], reception_time_ns: int) -> list[Row]:
        return [self.row(f, reception_time_ns) for f in frames]

    def frame(self, row: Sequence[Any]) -> TelemetryFrame:
        """The wire frame of a row of :attr:`columns` (a row read from storage: the
        buffer's ``last_queued_time_ns`` and ``capacity`` None)."""
        if len(row) != len(self.columns):
            raise FrameLayoutError(
                f"a row of {len(row)} values does not fit the layout ({self}): "
                f"it has {len(self.columns)}"
            )
        values: dict[str, Any] = {}
        at = 2
        for array, names in self.vectors:
            values[array] = [float(v) for v in row[at : at + len(names)]]
            at += len(names)
        mode, feedforward, queued, next_tag, last, _ = row[at:]
        return TelemetryFrame(
            seq=int(row[0]),
            generation_time_ns=int(row[1]),
            acs_mode=AcsModeName(str(mode)),
            acs_feedforward=bool(feedforward),
            buffer=BufferState(
                queued=int(queued),
                next_execute_time_ns=None if next_tag is None else int(next_tag),
                last_executed_seq=int(last),
            ),
            **values,
        )

    # --- rows <-> arrays --------------------------------------------------------------------

    def rows_to_arrays(self, rows: Sequence[Sequence[Any]]) -> FrameArrays:
        """Rows of :attr:`columns` (ascending, distinct ``seq``) as column arrays."""
        from telemetry.recording import FrameArrays

        n = len(rows)
        width = len(self.columns)
        for row in rows:
            if len(row) != width:
                raise FrameLayoutError(
                    f"a row of {len(row)} values does not fit the layout ({self}): it has {width}"
                )
        n_float = len(self.float_fields)
        numbers = np.array([row[2 : 2 + n_float] for row in rows], dtype=np.float64).reshape(
            n, n_float
        )
        at = 2 + n_float
        ints = np.array(
            [
                (r[0], r[1], r[-1], r[at + 2], -1 if r[at + 3] is None else r[at + 3], r[at + 4])
                for r in rows
            ],
            dtype=np.int64,
        ).reshape(n, 6)
        columns: dict[str, Any] = {
            "seq": ints[:, 0].copy(),
            "generation_time_ns": ints[:, 1].copy(),
            "reception_time_ns": ints[:, 2].copy(),
            "acs_mode": np.array([str(r[at]) for r in rows], dtype=np.str_).reshape(n),
            "acs_feedforward": np.array([bool(r[at + 1]) for r in rows], dtype=np.bool_).reshape(n),
            "buffer_queued": ints[:, 3].copy(),
            "buffer_next_execute_time_ns": ints[:, 4].copy(),
            "buffer_last_executed_seq": ints[:, 5].copy(),
        }
        start = 0
        for array, names in self.vectors:
            columns[array] = numbers[:, start : start + len(names)].copy()
            start += len(names)
        return FrameArrays(**columns)

    def arrays_to_rows(self, frames: FrameArrays) -> list[Row]:
        """Column arrays as rows of :attr:`columns`, plain Python values (a
        ``buffer_next_execute_time_ns`` of -1 becomes None)."""
        self.check_arrays(frames)
        numbers = np.hstack([getattr(frames, array) for array, _ in self.vectors]).tolist()
        next_tag = [None if t < 0 else t for t in frames.buffer_next_execute_time_ns.tolist()]
        columns = zip(
            frames.seq.tolist(),
            frames.generation_time_ns.tolist(),
            numbers,
            frames.acs_mode.tolist(),
            frames.acs_feedforward.tolist(),
            frames.buffer_queued.tolist(),
            next_tag,
            frames.buffer_last_executed_seq.tolist(),
            frames.reception_time_ns.tolist(),
            strict=True,
        )
        return [
            (seq, gen, *values, str(mode), bool(ff), queued, tag, last, rx)
            for seq, gen, values, mode, ff, queued, tag, last, rx in columns
        ]

    # --- wire <-> arrays --------------------------------------------------------------------

    def frames_to_arrays(
        self, frames: Sequence[TelemetryFrame], reception_time_ns: Sequence[int] | None = None
    ) -> FrameArrays:
        """Column arrays of wire frames (sorted by seq; the first copy of a seq kept).
        ``reception_time_ns`` defaults to each frame's generation time."""
        if reception_time_ns is None:
            reception_time_ns = [f.generation_time_ns for f in frames]
        if len(reception_time_ns) != len(frames):
            raise ValueError(f"{len(reception_time_ns)} reception times for {len(frames)} frames")
        first: dict[int, Row] = {}
        for frame, rx in zip(frames, reception_time_ns, strict=True):
            if frame.seq not in first:
                first[frame.seq] = self.row(frame, rx)
        return self.rows_to_arrays([first[s] for s in sorted(first)])

    def arrays_to_frames(self, frames: FrameArrays) -> list[TelemetryFrame]:
        """The wire frames of column arrays (buffer ``last_queued_time_ns`` and
        ``capacity`` None: the archive does not keep them)."""
        return [self.frame(row) for row in self.arrays_to_rows(frames)]


def _widths(frames: FrameArrays) -> tuple[int, int]:
    joints = np.shape(frames.joints_rad)
    wheels = np.shape(frames.wheel_speeds_radps)
    if len(joints) != 2 or len(wheels) != 2:
        raise FrameLayoutError(
            f"joints_rad of shape {joints} and wheel_speeds_radps of shape {wheels} are not "
            "one row per frame"
        )
    return int(joints[1]), int(wheels[1])


#: ETS-VII's layout: 6 joints, 3 wheels.
DEFAULT_LAYOUT = FrameLayout()
