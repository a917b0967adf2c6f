"""Flying planner plans through the :class:`~spacecraft.vehicle.Vehicle`, and the calibration
against the flight results (SPEC section 6 "Calibration", docs/spacecraft.md).

``python -m spacecraft._calibration`` prints the comparison table of docs/spacecraft.md
(about 10 s: four plan flights, some 1100 s of simulated flight at a few hundred times
real time).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from planner.coordination import REPORT_SETTLE_BAND_DEG
from planner.plan import Plan
from spacecraft.vehicle import Vehicle
from spacecraft.vehicle_config import VehicleConfig
from telemetry.wire import AcsCommandMsg, AcsModeName, CommandStage, JointCommandMsg

__all__ = [
    "PTP_SETTLE_S",
    "SETTLE_BAND_DEG",
    "Flight",
    "calibration_plans",
    "calibration_table",
    "coordination_metrics",
    "fly_plan",
    "plan_messages",
    "ptp_absolute_settling_s",
    "ptp_settling_s",
]

Array = NDArray[np.float64]

#: The epoch of calibration flights (any whole second works).
EPOCH_NS = 1_000_000_000_000_000_000
#: Plans start this long after the epoch, so that their first command is not late.
START_S = 1.0


def plan_messages(
    plan: Plan, *, epoch_ns: int, start_s: float = START_S, first_seq: int = 0
) -> list[JointCommandMsg | AcsCommandMsg]:
    """The plan's commands as uplink messages, tag = epoch + start + plan time, in tag order
    (an attitude command before a joint command with the same tag)."""
    t0_ns = epoch_ns + round(start_s * 1e9)
    msgs: list[tuple[int, int, JointCommandMsg | AcsCommandMsg]] = []
    for c in plan.acs_commands:
        tag = t0_ns + round(c.t_s * 1e9)
        msg = AcsCommandMsg(
            seq=0,
            execute_time_ns=tag,
            mode=AcsModeName(c.mode.value),
            target_quat_orbit_from_base_xyzw=list(c.target_quat_orbit_from_base_xyzw),
            feedforward=c.feedforward,
        )
        msgs.append((tag, 0, msg))
    for t_s, q in zip(plan.command_times_s, plan.command_joints_rad, strict=True):
        tag = t0_ns + round(float(t_s) * 1e9)
        msgs.append((tag, 1, JointCommandMsg(seq=0, execute_time_ns=tag, joints_rad=list(q))))
    msgs.sort(key=lambda m: (m[0], m[1]))
    return [m.model_copy(update={"seq": first_seq + k}) for k, (_, _, m) in enumerate(msgs)]


@dataclass(frozen=True, eq=False)
class Flight:
    """The truth sampled every ``sample_s`` from the plan's start (plan time ``t_s``)."""

    t_s: Array
    quat_orbit_from_base_xyzw: Array
    joints_rad: Array
    joint_targets_rad: Array
    wheel_momentum_nms: Array
    rejected: int

    @property
    def pitch_deg(self) -> Array:
        return np.asarray(
            Rotation.from_quat(self.quat_orbit_from_base_xyzw).as_euler("ZYX", degrees=True)[:, 1]
        )

    @property
    def attitude_deg(self) -> Array:
        """Angle of the base's rotation from the orbit frame."""
        return np.asarray(
            np.degrees(Rotation.from_quat(self.quat_orbit_from_base_xyzw).magnitude()), float
        )


def fly_plan(
    plan: Plan,
    config: VehicleConfig | None = None,
    *,
    seed: int = 0,
    tail_s: float = 0.0,
    sample_s: float = 0.1,
    lead_s: float = 5.0,
) -> Flight:
    """Fly ``plan`` from its initial joints: every command is uplinked ``lead_s`` before its
    tag (as the ground does, SPEC 6), the truth is sampled every ``sample_s``."""
    config = replace(
        config or VehicleConfig(),
        initial_joints_rad=tuple(float(x) for x in plan.initial_joints_rad),
    )
    vehicle = Vehicle(config, epoch_ns=EPOCH_NS, seed=seed)
    pending = plan_messages(plan, epoch_ns=EPOCH_NS)
    start_ns = EPOCH_NS + round(START_S * 1e9)
    n = round((plan.duration_s + tail_s) / sample_s) + 1
    rows: dict[str, list[Array]] = {k: [] for k in ("quat", "q", "target", "h")}
    rejected = 0
    k_msg = 0
    for i in range(n):
        t_ns = start_ns + round(i * sample_s * 1e9)
        while k_msg < len(pending) and pending[k_msg].execute_time_ns <= t_ns + lead_s * 1e9:
            ack = vehicle.receive(pending[k_msg])
            rejected += ack.stage is CommandStage.REJECTED
            k_msg += 1
        vehicle.advance_to(t_ns)
        state = vehicle.true_state()
        rows["quat"].append(state.quat_orbit_from_base_xyzw)
        rows["q"].append(state.joints_rad)
        rows["target"].append(vehicle.joint_target_rad())
        rows["h"].append(vehicle.wheel_momentum_nms())
    return Flight(
        t_s=np.arange(n, dtype=np.float64) * sample_s,
        quat_orbit_from_base_xyzw=np.array(rows["quat"]),
        joints_rad=np.array(rows["q"]),
        joint_targets_rad=np.array(rows["target"]),
        wheel_momentum_nms=np.array(rows["h"]),
        rejected=rejected,
    )


#: The settling band of the calibration: the pass report's.
SETTLE_BAND_DEG = REPORT_SETTLE_BAND_DEG
#: The report's final value: the mean over the window's last 5 s.
FINAL_S = 5.0


def _settling_s(t_s: Array, value_deg: Array, after_s: float, band_deg: float) -> float:
    """Time from ``after_s`` to the last sample outside ``band_deg`` (absolute: back to the
    nominal attitude)."""
    outside = np.flatnonzero(np.abs(value_deg) > band_deg)
    return max(0.0, float(t_s[outside[-1]]) - after_s) if outside.size else 0.0


def ptp_settling_s(
    flight: Flight, plan: Plan, *, band_deg: float = SETTLE_BAND_DEG, final_s: float = FINAL_S
) -> float:
    """The PTP A -> B's settling as the report measures it (``telemetry.analysis.reaction``):
    from the end of the motion until the base attitude stays within ``band_deg`` of its
    final value, the mean over the plan's last ``final_s``. With the calibration's long wait
    (:data:`PTP_SETTLE_S`) the final value is the attitude the loop holds: the nominal one,
    or, in the truth simulation, 0.015 deg off it in pitch at pose B, where the gravity
    gradient pulls against the wheels' proportional term. A PTP that has not settled by then
    counts as the whole wait."""
    from telemetry.analysis._common import settling_time_s

    end = plan.segment("A->B").t_end_s
    rotvec = Rotation.from_quat(flight.quat_orbit_from_base_xyzw).as_rotvec()
    settle, _ = settling_time_s(
        flight.t_s, rotvec, motion_end_s=end, band_rad=np.radians(band_deg), final_s=final_s
    )
    return float(flight.t_s[-1] - end) if settle is None else settle


def ptp_absolute_settling_s(
    flight: Flight, plan: Plan, *, band_deg: float = SETTLE_BAND_DEG
) -> float:
    """From the end of the PTP's motion until the base stays within ``band_deg`` of the
    nominal attitude (absolute: gravity gradient's offset included)."""
    return _settling_s(flight.t_s, flight.attitude_deg, plan.segment("A->B").t_end_s, band_deg)


def coordination_metrics(
    flight: Flight,
    plan: Plan,
    variant_label: str,
    *,
    band_deg: float = SETTLE_BAND_DEG,
    final_s: float = FINAL_S,
) -> dict[str, float]:
    """One variant of experiment 3 (segments ``(a)``, ``(b)`` or ``(c)``) as the report's
    phase plane measures it (``telemetry.analysis.phase_plane``): over the window from its
    forward leg's start to the next variant's start (or the plan's end), the pitch extremes
    and range, the first dip (forward leg), the peak before the back leg starts, and the
    settling time after the back leg to within ``band_deg`` of the attitude target in force
    at the window's end (the report's reference), and the pitch at its start
    (``start_pitch_deg``: the paper's variants each start at rest at the origin). A variant
    that has not stayed inside for ``final_s`` by then counts as the whole time left in its
    window (``settled`` 0)."""
    from telemetry.analysis._common import settling_time_s
    from telemetry.analysis.phase_plane import attitude_target_pitch_rad

    segs = [s for s in plan.segments if s.name.startswith(variant_label)]
    forward, back = (next(s for s in segs if s.name.endswith(word)) for word in ("forward", "back"))
    starts = sorted(
        s.t_start_s
        for s in plan.segments
        if s.kind == "coordination" and s.name.endswith(": forward")
    )
    later = [t for t in starts if t > forward.t_start_s]
    t0, fwd_end = forward.t_start_s, forward.t_end_s
    end = later[0] if later else plan.duration_s
    t, pitch = flight.t_s, flight.pitch_deg
    window = (t >= t0) & (t <= end)
    tw, pw = t[window], pitch[window]
    dev = np.column_stack([np.zeros(tw.size), np.radians(pw), np.zeros(tw.size)])
    target = attitude_target_pitch_rad(plan.acs_commands, end)
    settle, _ = settling_time_s(
        tw,
        dev,
        motion_end_s=back.t_end_s,
        band_rad=np.radians(band_deg),
        final_s=final_s,
        reference=None if target is None else np.array([0.0, target, 0.0]),
    )
    return {
        "pitch_min_deg": float(np.min(pw)),
        "pitch_max_deg": float(np.max(pw)),
        "pitch_range_deg": float(np.ptp(pw)),
        "first_dip_deg": float(np.min(pitch[(t >= t0) & (t <= fwd_end)])),
        "peak_before_back_leg_deg": float(np.max(pitch[(t >= t0) & (t < back.t_start_s)])),
        "settling_time_s": float(end - back.t_end_s) if settle is None else settle,
        "settled": float(settle is not None),
        "start_pitch_deg": float(pw[0]),
    }


#: The PTP's settling wait in calibration flights (s): long enough to see a calibrated law's
#: absolute settling (the default 120 s would cap it at the window's end).
PTP_SETTLE_S = 360.0


def calibration_plans(ws: Any) -> dict[str, Plan]:
    """The plans calibration flies: the PTP with a :data:`PTP_SETTLE_S` wait and experiment
    3 as the demo pass schedules it (``planner.schedule.PassParams``: no pause, 120 s
    settle), so that the calibration measures the variants the report judges."""
    from planner.coordination import CoordinationParams, plan_coordination
    from planner.experiments import PtpParams, plan_ptp
    from planner.schedule import PassParams

    pass_params = PassParams()
    return {
        "ptp": plan_ptp(ws, PtpParams(settle_s=PTP_SETTLE_S)),
        "coordination": plan_coordination(
            ws,
            CoordinationParams(
                pause_s=pass_params.coordination_pause_s,
                settle_s=pass_params.coordination_settle_s,
            ),
        ),
    }


def calibration_table(config: VehicleConfig | None = None) -> dict[str, dict[str, float]]:
    """The numbers of docs/spacecraft.md's calibration table, flown in the truth simulation."""
    from planner.coordination import CoordinationParams, plan_coordination
    from planner.dynamics import DynamicsWorkspace
    from planner.gjm import plan_gjm
    from planner.schedule import PassParams

    config = config or VehicleConfig()
    ws = DynamicsWorkspace(config.model)
    out: dict[str, dict[str, float]] = {}
    plans = calibration_plans(ws)

    ptp = plans["ptp"]
    flight = fly_plan(ptp, config)
    motion_end = ptp.segment("A->B").t_end_s
    out["ptp"] = {
        "peak_attitude_deg": float(np.max(flight.attitude_deg)),
        "settling_time_s": ptp_settling_s(flight, ptp),
        "absolute_settling_time_s": ptp_absolute_settling_s(flight, ptp),
        "absolute_settling_time_0.02deg_s": _settling_s(
            flight.t_s, flight.attitude_deg, motion_end, 0.02
        ),
        "attitude_100s_after_deg": float(
            np.interp(motion_end + 100.0, flight.t_s, flight.attitude_deg)
        ),
        "rejected": flight.rejected,
    }

    gjm = plan_gjm(ws)
    flight = fly_plan(gjm, config)
    pitch = flight.pitch_deg - flight.pitch_deg[0]
    retreat = gjm.segment("retreat")
    during = flight.t_s <= retreat.t_end_s
    out["gjm"] = {
        "base_pitch_change_deg": float(pitch[during][np.argmax(np.abs(pitch[during]))]),
        "final_pitch_drift_deg": float(pitch[-1] - pitch[during][-1]),
        "predicted_base_pitch_change_deg": gjm.metrics["base_pitch_change_deg"],
        "rejected": flight.rejected,
    }

    coordination = plans["coordination"]
    flight = fly_plan(coordination, config)
    for label, name in (("(a)", "feedback"), ("(b)", "feedforward"), ("(c)", "offset")):
        out[f"coordination_{name}"] = coordination_metrics(flight, coordination, label)
    out["coordination_feedback"]["rejected"] = flight.rejected
    # (c) again with the flight's -0.35 deg (FLIGHT_OFFSET_SCALE of eq. (10)'s Omega_b, the
    # default being Omega_b itself), after (a) as in the pass (a variant's start depends on
    # what came before)
    from planner.coordination import FLIGHT_OFFSET_SCALE

    pass_params = PassParams()
    flight_size = plan_coordination(
        ws,
        CoordinationParams(
            variants=("feedback", "offset"),
            offset_scale=FLIGHT_OFFSET_SCALE,
            pause_s=pass_params.coordination_pause_s,
            settle_s=pass_params.coordination_settle_s,
        ),
    )
    flight = fly_plan(flight_size, config)
    out["coordination_offset_flight_size"] = coordination_metrics(flight, flight_size, "(c)")
    return out


def main() -> None:
    for experiment, numbers in calibration_table().items():
        print(experiment)
        for key, value in numbers.items():
            print(f"    {key:28s} {value:10.3f}")


if __name__ == "__main__":
    main()
