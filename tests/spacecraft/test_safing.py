"""On-board safing and fault injection in the vehicle (spacecraft.safing, spacecraft.faults):
each fault shows in the measured telemetry as it should, and where it takes a safing quantity
past its red limit the vehicle is SAFE at the control tick that measures it: the arm holds,
the schedule is dropped (acknowledged ``safing``), attitude control holds the measured
attitude, commands are refused until ``safe_exit``. A nominal motion never safes
(docs/spacecraft.md, "On-board safing")."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from planner.clearance_watch import ClearanceWatch
from planner.description import default_robot
from planner.limits import Limits
from spacecraft.faults import parse_fault
from spacecraft.vehicle import Vehicle
from spacecraft.vehicle_config import VehicleConfig
from telemetry.limits import attitude_error_deg
from telemetry.wire import (
    AcsCommandMsg,
    AcsModeName,
    CommandAck,
    CommandStage,
    JointCommandMsg,
    RejectReason,
    SafeExit,
    TelemetryFrame,
)

EPOCH = 1_700_000_000_000_000_000
SECOND = 1_000_000_000
PERIOD = 250_000_000  # 4 Hz commands
CONTROL = 100_000_000  # the control period
STEP = 10_000_000  # the truth simulation's step
#: ETS-VII's red limits (its description's [limits]), which the built-in vehicle keeps
RED = default_robot().limits.safing_limits()
TRACKING = RED["joint_tracking_error_deg"]
ATTITUDE = RED["attitude_error_deg"]


def _vehicle(*faults: str, **fields: object) -> Vehicle:
    config = VehicleConfig(faults=tuple(parse_fault(f) for f in faults), **fields)  # type: ignore[arg-type]
    return Vehicle(config, epoch_ns=EPOCH, seed=5)


def _ramp(
    joint: int, rate_degps: float, start_s: float, duration_s: float
) -> list[JointCommandMsg]:
    """4 Hz commands moving joint ``joint`` (from 1) at ``rate_degps`` from the all-zero pose."""
    out = []
    for k in range(round(duration_s * 4) + 1):
        q = np.zeros(6)
        q[joint - 1] = math.radians(rate_degps * 0.25 * k)
        tag = EPOCH + round(start_s * SECOND) + k * PERIOD
        out.append(JointCommandMsg(seq=k, execute_time_ns=tag, joints_rad=list(q)))
    return out


def _received(v: Vehicle, commands: list[JointCommandMsg]) -> None:
    for cmd in commands:
        assert v.receive(cmd).stage is CommandStage.RECEIVED


def _error_deg(frame: TelemetryFrame, joint: int) -> float:
    return math.degrees(abs(frame.joint_targets_rad[joint - 1] - frame.joints_rad[joint - 1]))


def _attitude_deg(frames: list[TelemetryFrame]) -> np.ndarray:
    """Each frame's attitude error (abs, per axis) as the ground computes it."""
    quat = np.array([f.quat_orbit_from_base_xyzw for f in frames])
    target = np.array([f.acs_target_quat_xyzw for f in frames])
    return np.abs(attitude_error_deg(quat, target))


def _at(frames: list[TelemetryFrame], t_ns: int) -> TelemetryFrame:
    return next(f for f in frames if f.generation_time_ns == t_ns)


@dataclass
class Flight:
    vehicle: Vehicle
    acks: list[CommandAck]
    frames: list[TelemetryFrame]
    #: (time, truth value) at every simulation step while not safe
    truth: list[tuple[int, float]]


def _fly(v: Vehicle, end_s: float, truth: object = None) -> Flight:
    """Step by step to ``end_s`` (onboard s), sampling ``truth(vehicle)`` at every step
    until the vehicle is safe."""
    acks: list[CommandAck] = []
    frames: list[TelemetryFrame] = []
    samples: list[tuple[int, float]] = []
    t = v.onboard_time_ns
    end = EPOCH + round(end_s * SECOND)
    while t < end:
        if truth is None or v.safe:
            t = end
        else:
            t += STEP
        more_acks, more_frames = v.advance_to(t)
        acks += more_acks
        frames += more_frames
        if truth is not None and not v.safe:
            samples.append((t, float(truth(v))))  # type: ignore[operator]
    return Flight(v, acks, frames, samples)


def _safed_within_a_control_period(flight: Flight, limit: float, noise: float) -> None:
    """SAFE no earlier than the truth came within the sensor's noise (3 sigma) of the red
    limit, and at the first control tick after it crossed (if it did before SAFE: the
    measured sample may cross first)."""
    since = flight.vehicle.onboard_safing.since_ns
    assert since is not None
    near = next(t for t, value in flight.truth if value >= limit - 3.0 * noise)
    assert since >= near - STEP
    crossed = [t for t, value in flight.truth if value >= limit]
    if crossed:
        assert since <= crossed[0] + CONTROL
    else:
        assert since <= near + CONTROL


def _stuck_flight() -> Flight:
    """Joint 3 ramps at 1 deg/s from 2 s for 20 s; it sticks at 5 s."""
    v = _vehicle("joint3-stuck@5")
    _received(v, _ramp(3, 1.0, 2.0, 20.0))

    def truth_error_deg(vehicle: Vehicle) -> float:
        return math.degrees(abs(vehicle.joint_target_rad()[2] - vehicle.true_state().joints_rad[2]))

    return _fly(v, 30.0, truth_error_deg)


def test_a_stuck_joint_during_a_ramp_safes_within_one_control_period_of_the_crossing() -> None:
    flight = _stuck_flight()
    v, frames = flight.vehicle, flight.frames
    assert v.safe
    safing = v.onboard_safing
    since = safing.since_ns
    assert since is not None and safing.trigger is not None
    fault, entry = v.take_truth_events()
    assert fault["event"] == "fault" and fault["fault"] == "joint3-stuck"
    assert fault["onboard_time_ns"] == EPOCH + 5 * SECOND
    # telemetry: the measured joint stops where it stuck, the target reported goes on
    moving = [f for f in frames if EPOCH + 5 * SECOND < f.generation_time_ns < since]
    assert len(moving) > 15
    held = np.degrees([f.joints_rad[2] for f in moving])
    # the joint was moving at 1 deg/s: it overshoots a little, then settles in 1 s
    np.testing.assert_allclose(held, fault["held_deg"], atol=0.1)
    np.testing.assert_allclose(held[10:], fault["held_deg"], atol=0.05)
    targets = np.degrees([f.joint_targets_rad[2] for f in moving])
    np.testing.assert_allclose(np.diff(targets), 0.1, atol=1e-9)  # 1 deg/s at 10 Hz
    # the truth crossed the red limit; SAFE at the first control tick after (the measured
    # sample carries 0.005 deg of encoder noise: 5 ms at 1 deg/s)
    _safed_within_a_control_period(flight, TRACKING, 0.005)
    assert (since - EPOCH) % CONTROL == 0
    # the frame of that tick shows the value that tripped; the one before was below it
    tripped = _at(frames, since)
    assert _error_deg(tripped, 3) == pytest.approx(safing.trigger.value, rel=1e-12)
    assert _error_deg(tripped, 3) >= TRACKING > _error_deg(_at(frames, since - CONTROL), 3)
    assert (safing.trigger.quantity, safing.trigger.channel) == (
        "joint_tracking_error_deg",
        "joint3",
    )
    assert safing.trigger.limit == TRACKING
    assert entry["event"] == "safing_entry" and entry["onboard_time_ns"] == since
    assert (
        entry["quantity"] == "joint_tracking_error_deg" and entry["cancelled"] == safing.cancelled
    )


def test_a_fault_after_the_first_command_counts_from_its_execution_not_the_start() -> None:
    """``@cmd+T``: the fault's onset is T after the first time-tagged command executed on
    board (here at 7 s: the same stuck joint 3 s into the ramp as ``joint3-stuck@10``),
    whenever the commands were tagged; no command, no fault."""
    v = _vehicle("joint3-stuck@cmd+3")
    _received(v, _ramp(3, 1.0, 7.0, 20.0))
    flight = _fly(v, 30.0)
    fault, entry = flight.vehicle.take_truth_events()
    assert fault["spec"] == "joint3-stuck@cmd+3" and fault["at_s"] == 3.0
    assert fault["onboard_time_ns"] == EPOCH + 10 * SECOND
    assert fault["held_deg"] == pytest.approx(3.0, abs=0.6)  # 3 s at 1 deg/s, the servo's lag
    assert entry["event"] == "safing_entry" and entry["onboard_time_ns"] > EPOCH + 10 * SECOND
    idle = _vehicle("joint3-stuck@cmd+3")
    _fly(idle, 30.0)
    assert not idle.safe and idle.take_truth_events() == []


def test_after_safing_no_command_executes_and_the_arm_and_attitude_hold() -> None:
    flight = _stuck_flight()
    v, frames = flight.vehicle, flight.frames
    since = v.onboard_safing.since_ns
    assert since is not None
    executed = [a for a in flight.acks if a.stage is CommandStage.EXECUTED]
    assert executed and max(a.onboard_time_ns for a in executed) < since
    assert not [a for a in executed if a.onboard_time_ns >= since]  # 0 after safing
    dropped = [a for a in flight.acks if a.stage is CommandStage.REJECTED]
    expected = [c.seq for c in _ramp(3, 1.0, 2.0, 20.0) if c.execute_time_ns >= since]
    assert [a.seq for a in dropped] == expected and len(expected) > 50
    assert all(a.reason is RejectReason.SAFING and a.onboard_time_ns == since for a in dropped)
    assert v.onboard_safing.cancelled == len(expected)
    assert v.outcome(expected[-1]) == dropped[-1]
    # the arm holds the joints measured at the tick; attitude control holds its attitude
    tripped = _at(frames, since)
    after = [f for f in frames if f.generation_time_ns > since]
    assert len(after) > 70
    for f in after:
        np.testing.assert_array_equal(f.joint_targets_rad, tripped.joints_rad)
        np.testing.assert_array_equal(f.acs_target_quat_xyzw, tripped.quat_orbit_from_base_xyzw)
        assert f.acs_mode is AcsModeName.FEEDBACK and not f.acs_feedforward
        assert f.buffer.queued == 0
    spread = np.ptp(
        np.degrees([f.joints_rad for f in after if f.generation_time_ns > since + 3 * SECOND]),
        axis=0,
    )
    assert np.max(spread) < 0.05
    assert tripped.buffer.queued == len(expected)  # the tick's frame: the schedule as it stood
    # a report on entry, then every onboard second
    reports = v.take_safing_reports()
    assert [r.onboard_time_ns for r in reports] == list(range(since, v.onboard_time_ns + 1, SECOND))
    assert all(r.state == "safe" and r.since_time_ns == since for r in reports)
    assert reports[0].trigger == v.onboard_safing.trigger
    assert reports[0].cancelled == len(expected) and reports[0].exit_request_id is None


def test_commands_are_refused_while_safe_and_accepted_after_safe_exit() -> None:
    flight = _stuck_flight()
    v = flight.vehicle
    since = v.onboard_safing.since_ns
    now = v.onboard_time_ns
    hold = v.joint_target_rad()
    first = _ramp(3, 1.0, 2.0, 20.0)[-1]
    assert v.receive(first) == v.outcome(first.seq)  # a copy of a dropped one: its ack
    assert v.receive(first).reason is RejectReason.SAFING
    new = JointCommandMsg(seq=500, execute_time_ns=now + 2 * SECOND, joints_rad=list(hold))
    refused = v.receive(new)
    assert refused.stage is CommandStage.REJECTED and refused.reason is RejectReason.SAFING
    assert refused.detail is not None and "joint_tracking_error_deg joint3" in refused.detail
    acs = AcsCommandMsg(seq=501, execute_time_ns=now + 2 * SECOND, mode="free_drift")
    assert v.receive(acs).reason is RejectReason.SAFING
    assert v.queued == 0
    v.take_safing_reports()
    # safe_exit: answered nominal with its request_id, idempotent
    answer = v.safe_exit(SafeExit(request_id=7))
    assert not v.safe
    assert (answer.state, answer.exit_request_id, answer.since_time_ns) == ("nominal", 7, since)
    assert answer.onboard_time_ns == now and answer.trigger == v.onboard_safing.trigger
    assert v.safe_exit(SafeExit(request_id=7)) == answer
    *_, exit_record = v.take_truth_events()
    assert exit_record == {
        "event": "safing_exit",
        "onboard_time_ns": now,
        "onboard_s": (now - EPOCH) / SECOND,
        "request_id": 7,
        "since_time_ns": since,
    }
    # commands are accepted again: joint 1 moves (joint 3 is still stuck, and held)
    target = hold.copy()
    target[0] += math.radians(1.0)
    move = JointCommandMsg(seq=502, execute_time_ns=now + 2 * SECOND, joints_rad=list(target))
    assert v.receive(move).stage is CommandStage.RECEIVED
    acks, _ = v.advance_to(now + 5 * SECOND)
    assert [(a.seq, a.stage) for a in acks] == [(502, CommandStage.EXECUTED)]
    assert not v.safe and v.take_safing_reports() == []  # no more reports
    assert abs(v.true_state().joints_rad[0] - target[0]) < math.radians(0.05)


def test_safe_exit_when_not_safe_is_answered_nominal_and_changes_nothing() -> None:
    v = _vehicle()
    v.advance_to(EPOCH + SECOND)
    answer = v.safe_exit(SafeExit(request_id=3))
    assert (answer.state, answer.exit_request_id, answer.since_time_ns, answer.trigger) == (
        "nominal",
        3,
        None,
        None,
    )
    assert not v.safe and v.safing_report() is None and v.take_truth_events() == []


def test_a_drifting_joint_grows_a_tracking_error_the_target_does_not_show_and_safes() -> None:
    v = _vehicle("joint2-drift@5,rate_degps=1")
    before_ns = EPOCH + 5 * SECOND

    def truth_error_deg(vehicle: Vehicle) -> float:
        return math.degrees(abs(vehicle.joint_target_rad()[1] - vehicle.true_state().joints_rad[1]))

    flight = _fly(v, 20.0, truth_error_deg)
    since = v.onboard_safing.since_ns
    assert v.safe and since is not None
    frames = [f for f in flight.frames if f.generation_time_ns <= since]
    # the software's target (in telemetry) stays 0; the joint follows the drifting hardware
    assert all(f.joint_targets_rad == [0.0] * 6 for f in frames)
    drifting = [f for f in frames if f.generation_time_ns >= before_ns + 2 * SECOND]
    t_s = np.array([(f.generation_time_ns - before_ns) / SECOND for f in drifting])
    measured = np.degrees([f.joints_rad[1] for f in drifting])
    assert np.polyfit(t_s, measured, 1)[0] == pytest.approx(1.0, abs=0.01)  # 1 deg/s
    _safed_within_a_control_period(flight, TRACKING, 0.005)
    trigger = v.onboard_safing.trigger
    assert trigger is not None and trigger.channel == "joint2"
    assert _error_deg(_at(flight.frames, since), 2) == pytest.approx(trigger.value, rel=1e-12)
    # SAFE holds the software's target, but a hardware drift goes on (so does the ground's
    # alarm): the joint moves on at 1 deg/s from the target held
    after = [f for f in flight.frames if f.generation_time_ns > since]
    assert all(f.joint_targets_rad == after[0].joint_targets_rad for f in after)
    assert after[-1].generation_time_ns == EPOCH + 20 * SECOND
    assert _error_deg(after[-1], 2) == pytest.approx(15.0, abs=0.3)


def test_a_bump_in_free_drift_turns_the_base_past_its_red_attitude_limit_and_safes() -> None:
    v = _vehicle("bump@5,nms=30,axis=y")
    assert (
        v.receive(AcsCommandMsg(seq=0, execute_time_ns=EPOCH + SECOND, mode="free_drift")).stage
        is CommandStage.RECEIVED
    )

    def truth_error_deg(vehicle: Vehicle) -> float:
        quat = vehicle.true_state().quat_orbit_from_base_xyzw[None, :]
        return float(
            np.max(np.abs(attitude_error_deg(quat, vehicle.acs_target_quat_xyzw[None, :])))
        )

    flight = _fly(v, 30.0, truth_error_deg)
    since = v.onboard_safing.since_ns
    assert v.safe and since is not None
    frames = flight.frames
    # the gyro sees the bump at once: about 30 N m s / 3700 kg m^2 about base y
    rates = np.degrees([f.omega_base_in_base_radps[1] for f in frames])
    times = [f.generation_time_ns for f in frames]
    jump = rates[times.index(EPOCH + 5 * SECOND)] - rates[times.index(EPOCH + 5 * SECOND - CONTROL)]
    assert 0.35 < jump < 0.5
    _safed_within_a_control_period(flight, ATTITUDE, 0.005)
    trigger = v.onboard_safing.trigger
    assert trigger is not None and (trigger.quantity, trigger.channel) == (
        "attitude_error_deg",
        "y",
    )
    tripped = _at(frames, since)
    assert tripped.acs_mode is AcsModeName.FREE_DRIFT
    assert _attitude_deg([tripped])[0, 1] == pytest.approx(trigger.value, rel=1e-9)
    assert _attitude_deg([_at(frames, since - CONTROL)])[0, 1] < ATTITUDE
    # SAFE: feedback on the attitude measured at the tick, no feedforward
    assert v.acs_mode is AcsModeName.FEEDBACK and not v.acs_feedforward
    np.testing.assert_array_equal(v.acs_target_quat_xyzw, tripped.quat_orbit_from_base_xyzw)
    fault = v.take_truth_events()[0]
    assert fault["impulse_base_nms"] == [0.0, 30.0, 0.0]


def test_a_failed_wheel_leaves_a_bump_the_healthy_wheels_absorb_to_turn_the_base_until_safe() -> (
    None
):
    """A 5 N m s bump about base y while attitude control holds: the healthy wheels take it
    (the base turns by at most 1.5 deg and comes back); with wheel 2 (y) failed its speed
    stays put, nothing takes the momentum and the base turns on until the red limit."""
    healthy = _fly(_vehicle("bump@5,nms=5,axis=y"), 80.0)
    assert not healthy.vehicle.safe
    peak = np.max(_attitude_deg(healthy.frames))
    assert 1.0 < peak < 2.0  # measured 1.44 deg, 42 s
    wheel2 = np.array([f.wheel_momentum_nms[1] for f in healthy.frames])
    assert np.max(np.abs(wheel2)) > 5.0  # the y wheel took the bump: measured 7.1 N m s

    failed = _fly(_vehicle("wheel2-fail@3", "bump@5,nms=5,axis=y"), 80.0)
    v = failed.vehicle
    since = v.onboard_safing.since_ns
    assert v.safe and since is not None and since > EPOCH + 40 * SECOND
    trigger = v.onboard_safing.trigger
    assert trigger is not None and (trigger.quantity, trigger.channel) == (
        "attitude_error_deg",
        "y",
    )
    speeds = np.array(
        [
            f.wheel_speeds_radps[1]
            for f in failed.frames
            if f.generation_time_ns >= EPOCH + 3 * SECOND
        ]
    )
    # no torque: only the base's own turning (about 0.001 rad/s) changes its relative speed
    assert np.ptp(speeds) < 0.01
    assert [e["fault"] for e in v.take_truth_events()[:2]] == ["wheel2-fail", "bump"]


def test_a_failed_wheel_under_the_fastest_slew_shows_but_stays_below_red() -> None:
    """What a failed wheel alone does: joint 1 slewing at the 3 deg/s rate limit for 30 s
    (90 deg) while attitude control holds; wheel 1 (x) takes up to 6 N m s of the arm's
    reaction. Failed, its speed stays put and the base takes that reaction instead: a larger
    attitude error about x, but below red (ETS-VII's arm is light against its base), so no
    safing; a bump does the rest (the test above)."""
    runs = {}
    for faults in ((), ("wheel1-fail@1",)):
        v = _vehicle(*faults)
        _received(v, _ramp(1, 3.0, 2.0, 30.0))
        runs[faults] = _fly(v, 40.0)
        assert not v.safe
    healthy, failed = runs[()], runs[("wheel1-fail@1",)]
    peak_healthy = np.max(_attitude_deg(healthy.frames)[:, 0])
    peak_failed = np.max(_attitude_deg(failed.frames)[:, 0])
    assert peak_failed > 1.4 * peak_healthy  # measured 1.62 deg against 1.06
    assert peak_failed < 0.7 * ATTITUDE
    momentum = {
        k: np.max(np.abs([f.wheel_momentum_nms[0] for f in r.frames])) for k, r in runs.items()
    }
    assert momentum[()] > 5.0 and momentum[("wheel1-fail@1",)] < 0.01  # measured 6.0, 7e-4


def test_an_attitude_sensor_bias_above_the_red_limit_safes_at_once() -> None:
    v = _vehicle("attitude-bias@5,deg=4,axis=z")
    _, frames = v.advance_to(EPOCH + 5 * SECOND)
    truth = Rotation.from_quat(v.true_state().quat_orbit_from_base_xyzw)
    assert v.safe and v.onboard_safing.since_ns == EPOCH + 5 * SECOND
    read = Rotation.from_quat(frames[-1].quat_orbit_from_base_xyzw)
    bias = (truth.inv() * read).as_rotvec(degrees=True)
    np.testing.assert_allclose(bias, [0.0, 0.0, 4.0], atol=0.02)  # sensor noise 0.005 deg
    trigger = v.onboard_safing.trigger
    assert (
        trigger is not None
        and trigger.channel == "z"
        and trigger.value == pytest.approx(4.0, abs=0.05)
    )
    # feedback now holds what the sensor reads: the true attitude stays where it was
    v.advance_to(EPOCH + 30 * SECOND)
    moved = (truth.inv() * Rotation.from_quat(v.true_state().quat_orbit_from_base_xyzw)).magnitude()
    assert math.degrees(moved) < 0.1


def test_the_arm_driven_toward_the_base_safes_on_the_live_clearance() -> None:
    """Joint 2 at 3 deg/s to 60 deg brings the arm to the base's equipment: SAFE where the
    measured joints' clearance reaches the red 0.03 m, the arm held clear."""
    v = _vehicle()
    _received(v, _ramp(2, 3.0, 1.0, 20.0))
    flight = _fly(v, 25.0)
    since = v.onboard_safing.since_ns
    assert v.safe and since is not None
    trigger = v.onboard_safing.trigger
    assert trigger is not None and trigger.quantity == "clearance_m"
    assert trigger.limit == RED["clearance_m"] == 0.03
    watch = ClearanceWatch(default_robot(), math.inf)
    tripped = _at(flight.frames, since)
    assert watch.exact_m(np.array(tripped.joints_rad)) == pytest.approx(trigger.value, abs=1e-9)
    assert 0.0 < trigger.value <= 0.03
    assert watch.exact_m(np.array(_at(flight.frames, since - CONTROL).joints_rad)) > 0.03
    last = flight.frames[-1]
    assert watch.exact_m(np.array(last.joints_rad)) > 0.0  # held short of contact


def test_a_wheel_near_its_momentum_limit_safes_on_its_red_fraction() -> None:
    """With no red attitude limit (a [limits] table that gives attitude a watch band only),
    a 19.5 N m s bump about base x fills wheel 1 toward its 20 N m s: SAFE at 0.9."""
    limits = Limits.from_table({"attitude_error_deg": {"watch": 10.0}})
    v = _vehicle("bump@1,nms=19.5,axis=x", limits=limits)
    flight = _fly(v, 120.0)
    since = v.onboard_safing.since_ns
    assert v.safe and since is not None
    trigger = v.onboard_safing.trigger
    assert trigger is not None
    assert (trigger.quantity, trigger.channel, trigger.limit) == (
        "wheel_momentum_fraction",
        "wheel1",
        0.9,
    )
    tripped = _at(flight.frames, since)
    assert abs(tripped.wheel_momentum_nms[0]) / 20.0 == pytest.approx(trigger.value, rel=1e-12)
    assert abs(_at(flight.frames, since - CONTROL).wheel_momentum_nms[0]) / 20.0 < 0.9


def test_without_safing_a_fault_changes_nothing_on_board() -> None:
    v = _vehicle("attitude-bias@2,deg=5", safing=False)
    _received(v, _ramp(1, 2.0, 1.0, 5.0))
    acks, frames = v.advance_to(EPOCH + 10 * SECOND)
    assert not v.safe and v.take_safing_reports() == []
    assert [a.stage for a in acks] == [CommandStage.EXECUTED] * 21
    assert np.max(_attitude_deg(frames)) > 4.5  # what the ground's alarms will see
    assert [e["event"] for e in v.take_truth_events()] == ["fault"]


def test_the_tripping_sample_goes_down_even_between_telemetry_instants() -> None:
    """At 4 Hz telemetry a control tick (10 Hz) may fall between frames: the sample that
    tripped is sent as a frame of its own, so the ground sees the value."""
    v = _vehicle("attitude-bias@5.1,deg=4", telemetry_period_s=0.25)
    _, frames = v.advance_to(EPOCH + 6 * SECOND)
    times = [(f.generation_time_ns - EPOCH) / SECOND for f in frames]
    assert times[20:24] == [5.0, 5.1, 5.25, 5.5]
    assert [f.seq for f in frames] == list(range(len(frames)))
    assert _attitude_deg([frames[21]])[0, 0] > 3.9
    assert _attitude_deg([frames[22]])[0, 0] < 0.1  # the hold on the measured attitude


@pytest.mark.slow
def test_a_nominal_ptp_flown_through_the_vehicle_never_safes_nor_alarms() -> None:
    """ETS-VII's nominal PTP A -> B (its description's defaults, as the demo plans it), the
    commands uplinked as the ground does: the vehicle never safes, and the ground's
    evaluation of every frame finds nothing above the lowest band."""
    from spacecraft.nominal_limits import nominal_plan
    from spacecraft.vehicle_config import vehicle_config_for
    from telemetry.limits import for_description, interpolated_commands
    from telemetry.uplink import plan_commands

    robot = default_robot()
    plan = nominal_plan(robot, "ptp")
    start_ns = EPOCH + 5 * SECOND
    commands = plan_commands(plan, epoch_ns=start_ns, first_seq=0)
    joints = [c for c in commands if isinstance(c, JointCommandMsg)]
    v = Vehicle(vehicle_config_for(robot), epoch_ns=EPOCH, seed=1)
    motion_end = start_ns + round(plan.segment("A->B").t_end_s * SECOND)
    acks: list[CommandAck] = []
    frames: list[TelemetryFrame] = []
    k = 0
    for t in range(EPOCH + SECOND, motion_end + 10 * SECOND, SECOND):
        while k < len(commands) and commands[k].execute_time_ns <= t + 60 * SECOND:
            assert v.receive(commands[k]).stage is CommandStage.RECEIVED
            k += 1
        more_acks, more_frames = v.advance_to(t)
        acks += more_acks
        frames += more_frames
    assert not v.safe and v.onboard_safing.entries == 0 and v.take_safing_reports() == []
    assert not [a for a in acks if a.stage is CommandStage.REJECTED]
    executed = {a.seq for a in acks if a.stage is CommandStage.EXECUTED}
    assert {c.seq for c in joints if c.execute_time_ns <= motion_end} <= executed
    tags = np.array([c.execute_time_ns for c in joints], dtype=np.int64)
    evaluator = for_description(
        robot, commanded=interpolated_commands(tags, np.array([c.joints_rad for c in joints]))
    )
    values = evaluator.values(frames)
    # the motion was real: the joints lag their ramps, the base turns (the PTP's 0.5 deg)
    assert np.max(values["joint_tracking_error_deg"]) > 0.1
    assert np.max(values["attitude_error_deg"]) > 0.3
    readings = evaluator.evaluate(frames)
    lowest = {name: bands.thresholds[0][0] for name, bands in robot.limits.bands.items()}
    above = [r for r in readings if r.severity is not None and r.severity != lowest[r.quantity]]
    assert above == []


def test_the_vehicle_measures_the_attitude_error_as_the_ground_does() -> None:
    """The monitor's one-sample attitude error is the ground's batch function's, to rounding,
    the short way round included (a quaternion and its negative are one attitude)."""
    from spacecraft.safing import attitude_error_deg as onboard

    rng = np.random.default_rng(4)
    quats = Rotation.random(200, random_state=5).as_quat()
    targets = (
        Rotation.from_quat(quats) * Rotation.from_rotvec(rng.normal(0, 0.5, (200, 3)))
    ).as_quat()
    targets[::3] *= -1.0
    targets[1] = quats[1]  # no error at all
    ground = attitude_error_deg(quats, targets)
    ours = np.array([onboard(q, t) for q, t in zip(quats, targets, strict=True)])
    np.testing.assert_allclose(ours, ground, rtol=0, atol=1e-10)
    assert np.max(np.abs(ground)) > 60.0 and np.max(np.abs(ours[1])) < 1e-12


@pytest.mark.parametrize("safing", [True, False])
def test_a_diverging_simulation_safes_the_vehicle_and_streams_nothing(safing: bool) -> None:
    """Servos made unstable on purpose (ETS-VII's damping x10: past what RK4 at 10 ms holds,
    planner.servo_check), flown anyway through the vehicle's own config (a description
    with them is refused at load): the vehicle safes with ``simulation_diverged`` at the
    first instability, even flying without safing, drops its schedule, and generates no
    frame from then on (issue 28: 2,087 frames of a diverged Panda were archived)."""
    from planner.mjcf import ServoGains
    from planner.simulation import SimConfig, default_servo_gains

    model = default_robot().model
    gains = default_servo_gains(model)
    unstable = ServoGains(gains.kp_nm_per_rad, np.asarray(gains.kd_nms_per_rad) * 10.0)
    v = _vehicle(sim=SimConfig(servo=unstable), safing=safing)
    _received(v, _ramp(1, 2.0, 5.0, 5.0))
    acks, frames = v.advance_to(EPOCH + 20 * SECOND)  # MuJoCo warns on stderr, C side
    assert v.safe and v.diverged_ns is not None
    trigger = v.onboard_safing.trigger
    assert trigger is not None and trigger.quantity == "simulation_diverged"
    assert "diverged" in (trigger.detail or "")
    # the frames before the divergence only, every one of them physical
    assert v.diverged_ns - EPOCH == 200_000_000  # the first instability, 0.2 s in
    assert [f.generation_time_ns - EPOCH for f in frames] == [0, 100_000_000]
    assert all(max(abs(x) for x in f.joints_rad) < 1.0 for f in frames)
    # every queued command dropped, none executed
    assert {a.stage for a in acks} == {CommandStage.REJECTED}
    assert {a.reason for a in acks} == {RejectReason.SAFING}
    _, later = v.advance_to(EPOCH + 30 * SECOND)
    assert later == []
    truth = [e["event"] for e in v.take_truth_events()]
    assert "simulation_diverged" in truth and "safing_entry" in truth
