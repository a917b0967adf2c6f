"""Fault injection: what can go wrong on the simulated spacecraft, and when.

For rehearsals and tests (docs/spacecraft.md, "Faults"). ``hikoboshi spacecraft --fault
SPEC`` (repeatable) takes ``NAME@T[,key=value...]``, ``T`` in onboard seconds from the
spacecraft's start (as ``--outage``), or ``NAME@cmd+T[,...]``, ``T`` onboard seconds after the
vehicle executes its first time-tagged command (a pass's first command: "20 s into the
motion" whenever the ground starts it); the fault begins at the first step of the truth
simulation at or after that time:

- ``jointN-stuck@T``: joint N's servo holds where the joint is at T (it stops following its
  target);
- ``jointN-drift@T[,rate_degps=0.5]``: a bias growing at that rate is added to the servo
  target joint N's hardware applies (the onboard software's target, the one telemetry
  reports in ``joint_targets_rad``, is unchanged);
- ``jointN-offset@T[,deg=1.0]``: a constant bias of that angle is added to the same servo
  target from T on (a step, where a drift is a ramp: a zero offset in the joint's servo
  electronics; a negative angle turns the other way). The servo follows it as it follows a
  command, so the measured joint settles ``deg`` away from the software's target, and a
  link's nearest point moves about ``deg`` (in rad) times its lever toward or away from what
  it passes. An offset and a drift on one joint add up;
- ``wheelN-fail@T``: reaction wheel N gives no torque from T (it spins on freely);
- ``attitude-bias@T[,deg=3.0][,axis=x]``: the attitude sensor reads the attitude rotated by
  that angle about that base axis (``x``, ``y`` or ``z``; a negative angle turns the other
  way);
- ``bump@T[,nms=10][,axis=x]``: an external angular impulse on the base, N m s about that
  base axis (:meth:`planner.simulation.FreeFloatingSimulator.apply_base_impulse`).

A fault lives in the truth simulation only: nothing of it goes on the link, and the ground
learns of it from what the telemetry shows. :class:`FaultInjector` applies the faults of a
:class:`~spacecraft.vehicle_config.VehicleConfig` in the vehicle's truth simulation and returns a
record of each onset for the truth log (:mod:`spacecraft.truth`).
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from planner.simulation import FreeFloatingSimulator
from spacecraft._sensors import Measurement

__all__ = [
    "FAULT_KINDS",
    "Fault",
    "FaultInjector",
    "FaultSpecError",
    "check_faults",
    "parse_fault",
]

Array = NDArray[np.float64]
FaultKind = Literal[
    "joint-stuck", "joint-drift", "joint-offset", "wheel-fail", "attitude-bias", "bump"
]
Axis = Literal["x", "y", "z"]

#: The fault kinds, as their names are written (N: the joint's or wheel's number, from 1).
FAULT_KINDS = (
    "jointN-stuck",
    "jointN-drift",
    "jointN-offset",
    "wheelN-fail",
    "attitude-bias",
    "bump",
)
#: Each kind's parameters and their defaults.
_PARAMETERS: dict[str, dict[str, float | str]] = {
    "joint-stuck": {},
    "joint-drift": {"rate_degps": 0.5},
    "joint-offset": {"deg": 1.0},
    "wheel-fail": {},
    "attitude-bias": {"deg": 3.0, "axis": "x"},
    "bump": {"nms": 10.0, "axis": "x"},
}
_AXES: dict[str, int] = {"x": 0, "y": 1, "z": 2}
_NAME = re.compile(r"^(?:(joint|wheel)(\d+)-(stuck|drift|offset|fail)|(attitude-bias|bump))$")
#: A fault after this many onboard seconds is a typing error (a year).
_MAX_AT_S = 365.25 * 86400.0


class FaultSpecError(ValueError):
    """A ``--fault`` that cannot be read, or that names what the robot does not have."""


@dataclass(frozen=True)
class Fault:
    """One fault: its kind, its onset (onboard seconds from the start), the joint or wheel
    (numbered from 1) it hits, and its parameters (``None`` where the kind has none)."""

    kind: FaultKind
    at_s: float
    index: int | None = None
    #: ``at_s`` counts from the first time-tagged command executed on board (``@cmd+T``),
    #: not from the spacecraft's start
    after_first_command: bool = False
    rate_degps: float | None = None
    deg: float | None = None
    nms: float | None = None
    axis: Axis | None = None

    @property
    def name(self) -> str:
        """``joint3-stuck``, ``wheel2-fail``, ``attitude-bias``, ``bump``."""
        if self.kind in ("joint-stuck", "joint-drift", "joint-offset", "wheel-fail"):
            part, _, what = self.kind.partition("-")
            return f"{part}{self.index}-{what}"
        return self.kind

    @property
    def spec(self) -> str:
        """The fault written as ``--fault`` takes it (every parameter explicit)."""
        params = [
            f"{key}={getattr(self, key):g}" if key != "axis" else f"axis={self.axis}"
            for key in _PARAMETERS[self.kind]
        ]
        when = f"cmd+{self.at_s:g}" if self.after_first_command else f"{self.at_s:g}"
        return ",".join([f"{self.name}@{when}", *params])

    def parameters(self) -> dict[str, Any]:
        """The kind's parameters, for the truth log."""
        out: dict[str, Any] = {key: getattr(self, key) for key in _PARAMETERS[self.kind]}
        if self.kind.startswith("joint"):
            out["joint"] = self.index
        elif self.kind == "wheel-fail":
            out["wheel"] = self.index
        return out


def parse_fault(text: str) -> Fault:
    """Read one ``--fault`` (the module docstring gives the grammar); raises
    :class:`FaultSpecError` naming what is wrong. Joint and wheel numbers are checked against
    a robot by :func:`check_faults`."""
    where = f"fault {text!r}"
    head, sep, rest = text.strip().partition("@")
    if not sep:
        raise FaultSpecError(
            f"{where}: needs NAME@T (T in onboard seconds from the spacecraft's start) or "
            "NAME@cmd+T (T after the first command executed), e.g. joint3-stuck@120"
        )
    match = _NAME.match(head.strip())
    if match is None:
        raise FaultSpecError(
            f"{where}: unknown fault {head.strip()!r}; known: {', '.join(FAULT_KINDS)}"
        )
    part, number, what, whole = match.groups()
    index: int | None = None
    if whole is not None:
        kind = whole
    else:
        kind = f"{part}-{what}"
        if kind not in _PARAMETERS:
            raise FaultSpecError(
                f"{where}: a {part} can be {' or '.join(_whats(part))}, not {what!r}"
            )
        index = int(number)
        if index < 1:
            raise FaultSpecError(f"{where}: {part}s are numbered from 1 ({part}1, {part}2, ...)")
    time_text, *pairs = rest.split(",")
    anchor, plus, after = time_text.strip().partition("+")
    relative = bool(plus) and anchor.strip() == "cmd"
    at_s = _number(where, "T", after if relative else time_text)
    if not 0.0 <= at_s <= _MAX_AT_S:
        since = "the first command executed" if relative else "the spacecraft's start"
        raise FaultSpecError(
            f"{where}: T = {at_s:g} s must lie in [0, {_MAX_AT_S:g}] (onboard seconds from {since})"
        )
    allowed = _PARAMETERS[kind]
    values: dict[str, float | str] = dict(allowed)
    for pair in pairs:
        key, eq, value = pair.partition("=")
        key = key.strip()
        if not eq:
            raise FaultSpecError(f"{where}: {pair!r} is not key=value")
        if key not in allowed:
            takes = ", ".join(allowed) if allowed else "no parameter"
            raise FaultSpecError(f"{where}: {kind} takes {takes}; not {key!r}")
        if key == "axis":
            axis = value.strip()
            if axis not in _AXES:
                raise FaultSpecError(f"{where}: axis must be x, y or z, got {axis!r}")
            values[key] = axis
        else:
            number = _number(where, key, value)
            if number == 0.0:
                raise FaultSpecError(f"{where}: {key} = 0 is no fault")
            if key == "deg" and abs(number) >= 180.0:
                raise FaultSpecError(f"{where}: deg = {number:g} must lie within +-180")
            values[key] = number
    fault = Fault(
        kind=kind,  # type: ignore[arg-type]
        at_s=at_s,
        index=index,
        after_first_command=relative,
    )
    return replace(fault, **values)  # type: ignore[arg-type]


def _whats(part: str) -> list[str]:
    return [k.split("-", 1)[1] for k in _PARAMETERS if k.startswith(f"{part}-")]


def _number(where: str, key: str, text: str) -> float:
    try:
        value = float(text.strip())
    except ValueError:
        raise FaultSpecError(f"{where}: {key} = {text.strip()!r} is not a number") from None
    if not math.isfinite(value):
        raise FaultSpecError(f"{where}: {key} = {text.strip()!r} is not finite")
    return value


def check_faults(faults: Iterable[Fault], *, n_joints: int, n_wheels: int) -> None:
    """Refuse a fault on a joint or wheel the robot does not have, naming it."""
    for fault in faults:
        if fault.index is None:
            continue
        part, count = ("joint", n_joints) if fault.kind.startswith("joint") else ("wheel", n_wheels)
        if fault.index > count:
            raise FaultSpecError(
                f"fault {fault.spec!r}: the robot has {count} {part}s ({part}1 to {part}{count}), "
                f"no {part}{fault.index}"
            )


class FaultInjector:
    """The faults' effect on the truth simulation (state: which have begun, and what they
    hold). The vehicle asks it for the next onset, calls :meth:`begin` there, and passes the
    servo targets, wheel torques and sensor samples through it."""

    def __init__(self, faults: Sequence[Fault], *, epoch_ns: int, step_ns: int) -> None:
        self._epoch_ns, self._step_ns = epoch_ns, step_ns
        #: (onset ns, order given, fault), the next last; the ``@cmd+T`` faults join it
        #: once the first command executes (:meth:`first_command`)
        self._pending = sorted(
            (
                (self._onset(epoch_ns, f), i, f)
                for i, f in enumerate(faults)
                if not f.after_first_command
            ),
            reverse=True,
        )
        self._after_command = [(i, f) for i, f in enumerate(faults) if f.after_first_command]
        #: joint index (from 0) -> the angle its servo holds
        self.stuck: dict[int, float] = {}
        #: joint index (from 0) -> (bias rad at t0, bias rate rad/s, t0 ns): the drifts' and
        #: offsets' sum on each joint's servo target
        self.bias: dict[int, tuple[float, float, int]] = {}
        self.failed_wheels: set[int] = set()
        self._bias: Rotation | None = None

    def _onset(self, since_ns: int, fault: Fault) -> int:
        """The first step of the truth simulation at or after ``fault.at_s`` past
        ``since_ns``."""
        late_ns = since_ns - self._epoch_ns + round(fault.at_s * 1e9)
        return self._epoch_ns + math.ceil(late_ns / self._step_ns) * self._step_ns

    def first_command(self, t_ns: int) -> None:
        """A time-tagged command executed at ``t_ns``: the first one sets the onsets of the
        ``@cmd+T`` faults (later ones change nothing)."""
        for i, fault in self._after_command:
            self._pending.append((self._onset(t_ns, fault), i, fault))
        if self._after_command:
            self._after_command = []
            self._pending.sort(reverse=True)

    @property
    def next_onset_ns(self) -> int | None:
        return self._pending[-1][0] if self._pending else None

    def begin(self, t_ns: int, sim: FreeFloatingSimulator) -> list[dict[str, Any]]:
        """Start every fault due at ``t_ns`` (the truth simulation stands at ``t_ns``):
        the truth log's record of each."""
        records = []
        while self._pending and self._pending[-1][0] <= t_ns:
            _, _, fault = self._pending.pop()
            record: dict[str, Any] = {
                "event": "fault",
                "fault": fault.name,
                "kind": fault.kind,
                "spec": fault.spec,
                "at_s": fault.at_s,
                "onboard_time_ns": t_ns,
                "onboard_s": (t_ns - self._epoch_ns) / 1e9,
                **fault.parameters(),
            }
            record.update(self._start(fault, t_ns, sim))
            records.append(record)
        return records

    def _start(self, fault: Fault, t_ns: int, sim: FreeFloatingSimulator) -> dict[str, Any]:
        if fault.kind == "joint-stuck":
            assert fault.index is not None
            j = fault.index - 1
            angle = self.stuck.setdefault(j, float(sim.state().joints_rad[j]))
            return {"held_deg": math.degrees(angle)}
        if fault.kind in ("joint-drift", "joint-offset"):
            assert fault.index is not None
            j = fault.index - 1
            bias, rate, since = self.bias.get(j, (0.0, 0.0, t_ns))
            # the bias so far, then this fault's step or rate added from now on
            bias += rate * (t_ns - since) / 1e9 + math.radians(fault.deg or 0.0)
            self.bias[j] = (bias, rate + math.radians(fault.rate_degps or 0.0), t_ns)
            return {}
        if fault.kind == "wheel-fail":
            assert fault.index is not None
            self.failed_wheels.add(fault.index - 1)
            return {}
        axis = np.zeros(3)
        axis[_AXES[fault.axis or "x"]] = 1.0
        if fault.kind == "attitude-bias":
            assert fault.deg is not None
            bias = Rotation.from_rotvec(math.radians(fault.deg) * axis)
            self._bias = bias if self._bias is None else self._bias * bias
            return {}
        assert fault.nms is not None
        sim.apply_base_impulse(fault.nms * axis)
        return {"impulse_base_nms": (fault.nms * axis).tolist()}

    def servo(self, target_rad: Array, rate_radps: Array, t_ns: int) -> tuple[Array, Array]:
        """The target (and its rate) the joint servos' hardware applies, from the onboard
        software's: a stuck joint holds its angle, a drifting or offset one adds its bias."""
        if not self.stuck and not self.bias:
            return target_rad, rate_radps
        target, rate = target_rad.copy(), rate_radps.copy()
        for j, (bias, bias_rate, since) in self.bias.items():
            target[j] += bias + bias_rate * (t_ns - since) / 1e9
            rate[j] += bias_rate
        for j, angle in self.stuck.items():
            target[j], rate[j] = angle, 0.0
        return target, rate

    def wheel_torque(self, torque_nm: Array) -> Array:
        """The motor torques the wheels give: none from a failed wheel."""
        if not self.failed_wheels:
            return torque_nm
        out = torque_nm.copy()
        out[sorted(self.failed_wheels)] = 0.0
        return out

    def sense(self, measurement: Measurement) -> Measurement:
        """The sensor sample as the faulty sensors give it: the attitude rotated by the
        bias (in the base frame, as the sensor noise is)."""
        if self._bias is None:
            return measurement
        rot = Rotation.from_quat(measurement.quat_orbit_from_base_xyzw) * self._bias
        quat = np.asarray(rot.as_quat(), dtype=np.float64)
        if quat[3] < 0.0:
            quat = -quat
        return replace(measurement, quat_orbit_from_base_xyzw=quat)
