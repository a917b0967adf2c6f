"""A flown pass as arrays: what the analyses, the MCAP recorder and replay work from.

One :class:`PassRecording` holds everything the ground kept of a pass: the plan that was
uplinked (with its prediction), the plan's onboard epoch, the telemetry frames as column
arrays (row ``k`` is the frame with ``seq[k]``, rows in ascending ``seq``), the commands with
the time each stage was reached, the audit events, and the alarms (each its JSON document,
docs/alarms.md). It is pure data: the server builds one
from its database, the MCAP reader from a file, tests from an offline flight.

Times follow the storage conventions: ``generation_time_ns`` and the acknowledgement stages
of a command are onboard time; ``reception_time_ns`` and the other stages are ground time.
:meth:`PassRecording.t_s` puts frames on the plan's clock (s from the plan's ``t = 0``).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from planner.plan import Plan
from telemetry.alarm import AlarmPublic
from telemetry.layout import DEFAULT_LAYOUT, FrameLayout
from telemetry.wire import (
    MAX_BASE_RATE_RADPS,
    MAX_JOINT_ABS_RAD,
    MAX_WHEEL_SPEED_RADPS,
    TelemetryFrame,
)

__all__ = [
    "FRAME_ARRAYS",
    "CommandRow",
    "EventRow",
    "FrameArrays",
    "PassRecording",
    "UnphysicalTelemetry",
    "check_physical",
    "frames_to_arrays",
]

Array = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Column name -> row width (1 = one value per frame) of ETS-VII's frames; another robot's
#: is its layout's (:attr:`telemetry.layout.FrameLayout.arrays`). Units as in telemetry.wire.
FRAME_ARRAYS: dict[str, int] = DEFAULT_LAYOUT.arrays


@dataclass(frozen=True, eq=False)
class FrameArrays:
    """Telemetry frames as columns, one row per frame, ascending ``seq``; the widths are
    those of one :class:`~telemetry.layout.FrameLayout` (:attr:`layout`)."""

    seq: IntArray
    generation_time_ns: IntArray
    reception_time_ns: IntArray
    joints_rad: Array
    joint_targets_rad: Array
    quat_orbit_from_base_xyzw: Array
    omega_base_in_base_radps: Array
    wheel_speeds_radps: Array
    wheel_momentum_nms: Array
    acs_mode: NDArray[np.str_]
    acs_target_quat_xyzw: Array
    acs_feedforward: NDArray[np.bool_]
    buffer_queued: IntArray
    buffer_next_execute_time_ns: IntArray
    buffer_last_executed_seq: IntArray

    def __post_init__(self) -> None:
        n = len(self.seq)
        for name, width in FrameLayout.of_arrays(self).arrays.items():
            shape = np.shape(getattr(self, name))
            want = (n,) if width == 1 else (n, width)
            if shape != want:
                raise ValueError(f"frame column {name} has shape {shape}, expected {want}")
        if n > 1 and not bool(np.all(np.diff(self.seq) > 0)):
            raise ValueError("frame rows must be in strictly ascending seq")

    def __len__(self) -> int:
        return len(self.seq)

    @property
    def layout(self) -> FrameLayout:
        """The layout of these columns (their joint and wheel counts)."""
        return FrameLayout.of_arrays(self)

    def take(self, rows: IntArray | NDArray[np.bool_] | slice) -> FrameArrays:
        """A copy of the selected rows (an index array, a mask or a slice): never a view,
        so changing it leaves this one as it was."""
        return FrameArrays(
            **{name: getattr(self, name)[rows].copy() for name in self.layout.arrays}
        )

    @classmethod
    def empty(cls, layout: FrameLayout = DEFAULT_LAYOUT) -> FrameArrays:
        return layout.rows_to_arrays([])


def frames_to_arrays(
    frames: Sequence[TelemetryFrame],
    reception_time_ns: Sequence[int] | None = None,
    layout: FrameLayout | None = None,
) -> FrameArrays:
    """Column arrays of wire frames (sorted by seq; the first copy of a seq kept).
    ``reception_time_ns`` defaults to each frame's generation time; ``layout`` to the first
    frame's own (ETS-VII's for none). A frame of another shape raises
    :class:`~telemetry.layout.FrameLayoutError`."""
    if layout is None:
        layout = FrameLayout.of_frame(frames[0]) if frames else DEFAULT_LAYOUT
    return layout.frames_to_arrays(frames, reception_time_ns)


@dataclass(frozen=True)
class CommandRow:
    """One command of the pass and the time it reached each stage (``None``: never).
    ``payload`` is the kind's own wire fields (``joints_rad``; or ``mode``,
    ``target_quat_orbit_from_base_xyzw``, ``feedforward``)."""

    seq: int
    kind: str
    execute_time_ns: int
    payload: Mapping[str, Any]
    stage: str
    reject_reason: str | None = None
    stage_times_ns: Mapping[str, int | None] = field(default_factory=dict)


@dataclass(frozen=True)
class EventRow:
    """An audit event: ``actor`` did ``kind`` at ``time_ns`` (ground)."""

    time_ns: int
    kind: str
    actor: str
    detail: Mapping[str, Any]


@dataclass(frozen=True, eq=False)
class PassRecording:
    """Everything kept of one pass (see the module doc)."""

    name: str
    plan: Plan
    #: Onboard time of the plan's t = 0.
    epoch_ns: int
    frames: FrameArrays
    commands: tuple[CommandRow, ...] = ()
    events: tuple[EventRow, ...] = ()
    #: Free-form facts about the pass (id, state, relay, AOS/LOS, source).
    meta: Mapping[str, Any] = field(default_factory=dict)
    #: The pass's alarms, oldest raised first (docs/alarms.md), each its ``timeline`` of band
    #: changes included.
    alarms: tuple[AlarmPublic, ...] = ()

    def t_s(self) -> Array:
        """Frame times on the plan's clock: s from the plan's ``t = 0``."""
        return (self.frames.generation_time_ns - self.epoch_ns).astype(np.float64) / 1e9

    @classmethod
    def from_frames(
        cls,
        name: str,
        plan: Plan,
        epoch_ns: int,
        frames: Iterable[TelemetryFrame],
        **kwargs: Any,
    ) -> PassRecording:
        return cls(name, plan, epoch_ns, frames_to_arrays(list(frames)), **kwargs)


class UnphysicalTelemetry(ValueError):
    """A recording whose frames no real vehicle can have sent (a diverged simulation, an
    imported file): no analysis may call it a result. The message names the first such
    frame and the quantity."""


def check_physical(frames: FrameArrays) -> None:
    """Raise :class:`UnphysicalTelemetry` when any frame is non-finite or beyond the wire's
    bounds (``telemetry.wire``'s ``MAX_*``, which the ground already refuses at reception:
    this catches recordings that came another way)."""
    columns = {
        "joints_rad": (frames.joints_rad, MAX_JOINT_ABS_RAD, "rad"),
        "joint_targets_rad": (frames.joint_targets_rad, MAX_JOINT_ABS_RAD, "rad"),
        "omega_base_in_base_radps": (frames.omega_base_in_base_radps, MAX_BASE_RATE_RADPS, "rad/s"),
        "wheel_speeds_radps": (frames.wheel_speeds_radps, MAX_WHEEL_SPEED_RADPS, "rad/s"),
        "quat_orbit_from_base_xyzw": (frames.quat_orbit_from_base_xyzw, 1.1, ""),
    }
    for name, (values, bound, unit) in columns.items():
        values = np.asarray(values, dtype=np.float64)
        if len(values) == 0:  # no frame: nothing unphysical (the analyses say "no data")
            continue
        bad = ~np.isfinite(values) | (np.abs(np.nan_to_num(values, nan=np.inf)) > bound)
        rows = np.flatnonzero(bad.reshape(len(values), -1).any(axis=1))
        if rows.size:
            k = int(rows[0])
            worst = (
                values[k][np.argmax(bad.reshape(len(values), -1)[k])]
                if values.ndim > 1
                else values[k]
            )
            raise UnphysicalTelemetry(
                f"{rows.size} of {len(values)} frames are not physical, the first seq "
                f"{int(frames.seq[k])}: {name} {float(worst):.6g} {unit} (beyond {bound:.6g} "
                f"{unit} or not finite): a diverged simulation is not analysed".replace("  ", " ")
            )
