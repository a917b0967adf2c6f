"""The flight segment (spacecraft.vehicle): onboard command rules (retransmitted copies, the
schedule's capacity, schedule_delete), execution on the time grid, the LOS policy and the
safe state, truth-simulation invariants, attitude control, telemetry, and the calibration
against the flight results (docs/spacecraft.md)."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from planner.dynamics import DynamicsWorkspace
from planner.model import default_model
from planner.plan import Plan
from planner.simulation import SimConfig
from spacecraft._calibration import coordination_metrics, fly_plan, plan_messages
from spacecraft.vehicle import Vehicle
from spacecraft.vehicle_config import SensorNoise, VehicleConfig, VehicleError
from telemetry.wire import (
    DEFAULT_SCHEDULE_CAPACITY,
    AcsCommandMsg,
    AcsModeName,
    CommandAck,
    CommandStage,
    JointCommandMsg,
    RejectReason,
    ScheduleDelete,
    TelemetryFrame,
)

EPOCH = 1_700_000_000_000_000_000
PERIOD = 250_000_000  # 4 Hz commands
SECOND = 1_000_000_000
T0 = EPOCH + 2 * SECOND  # first tag used by most tests
IDENTITY = [0.0, 0.0, 0.0, 1.0]


@pytest.fixture(scope="module")
def config() -> VehicleConfig:
    return VehicleConfig()  # defaults: gravity gradient on, calibrated gains, noise


def _vehicle(config: VehicleConfig, seed: int = 7) -> Vehicle:
    return Vehicle(config, epoch_ns=EPOCH, seed=seed)


def _joints(seq: int, tag: int, deg: list[float] | np.ndarray) -> JointCommandMsg:
    return JointCommandMsg(seq=seq, execute_time_ns=tag, joints_rad=list(np.radians(deg)))


def _ramp_deg(k: int) -> np.ndarray:
    """Command k of a motion at 2 deg/s on joint 1 and -1 deg/s on joint 4 (within 3 deg/s)."""
    return np.array([0.5 * k, 0.0, 0.0, -0.25 * k, 0.0, 0.0])


def _received(ack: CommandAck) -> None:
    assert ack.stage is CommandStage.RECEIVED, ack


def _rejected(ack: CommandAck, reason: RejectReason, *words: str) -> None:
    assert ack.stage is CommandStage.REJECTED and ack.reason is reason, ack
    for word in words:
        assert ack.detail is not None and word in ack.detail, (word, ack.detail)


# -- execution on the grid ----------------------------------------------------------------


def test_commands_execute_exactly_at_their_tags_with_linear_ramps(config: VehicleConfig) -> None:
    v = _vehicle(config)
    tags = [T0 + k * PERIOD for k in range(6)]
    for k, tag in enumerate(tags):
        _received(v.receive(_joints(k, tag, _ramp_deg(k))))
    assert v.queued == 6 and v.last_command_seq == 5
    executed: list[CommandAck] = []
    for k, tag in enumerate(tags):
        acks, _ = v.advance_to(tag)
        executed += acks
        assert v.onboard_time_ns == tag
        # the servo target is the commanded joints, exactly, at the tag
        np.testing.assert_array_equal(v.joint_target_rad(), np.radians(_ramp_deg(k)))
        if k + 1 < len(tags):
            # ... and moves linearly toward the next command in between (40 % and 80 %)
            for fraction in (0.4, 0.8):
                v.advance_to(tag + round(fraction * PERIOD))
                expected = np.radians(_ramp_deg(k) + fraction * (_ramp_deg(k + 1) - _ramp_deg(k)))
                np.testing.assert_allclose(v.joint_target_rad(), expected, rtol=0, atol=1e-12)
    assert [a.seq for a in executed] == list(range(6))
    assert all(a.stage is CommandStage.EXECUTED for a in executed)
    assert [a.onboard_time_ns for a in executed] == tags
    # the last one holds
    v.advance_to(tags[-1] + 3 * SECOND)
    np.testing.assert_array_equal(v.joint_target_rad(), np.radians(_ramp_deg(5)))


def test_one_long_advance_executes_everything_in_time_order(config: VehicleConfig) -> None:
    v = _vehicle(config)
    tags = [T0 + k * PERIOD for k in range(8)]
    # uplinked out of order, with an attitude command sharing a tag with a joint command
    for k in (3, 0, 7, 1, 5, 2, 6, 4):
        _received(v.receive(_joints(k, tags[k], _ramp_deg(k))))
    _received(v.receive(AcsCommandMsg(seq=21, execute_time_ns=tags[2], mode="free_drift")))
    # attitude commands may share a tag (plans repeat one at a segment boundary): seq order
    _received(v.receive(AcsCommandMsg(seq=20, execute_time_ns=tags[2], mode="feedback")))
    acks, frames = v.advance_to(tags[-1] + 55_000_000)  # off the 10 ms grid: floors to it
    assert v.onboard_time_ns == tags[-1] + 50_000_000
    assert [(a.seq, a.onboard_time_ns) for a in acks] == sorted(
        [(k, tags[k]) for k in range(8)] + [(20, tags[2]), (21, tags[2])],
        key=lambda x: (x[1], x[0]),
    )
    assert v.acs_mode is AcsModeName.FREE_DRIFT  # seq 21, the last at that tag
    assert frames[-1].buffer.last_executed_seq == 7 and frames[-1].buffer.queued == 0
    # the clock never goes back
    assert v.advance_to(EPOCH) == ([], [])
    assert v.onboard_time_ns == tags[-1] + 50_000_000


def test_a_missing_successor_holds_then_the_late_successor_is_ramped_to(
    config: VehicleConfig,
) -> None:
    v = _vehicle(config)
    _received(v.receive(_joints(0, T0, _ramp_deg(0))))
    _received(v.receive(_joints(1, T0 + PERIOD, _ramp_deg(1))))
    v.advance_to(T0 + PERIOD + 50_000_000)
    held = np.radians(_ramp_deg(1))
    np.testing.assert_array_equal(v.joint_target_rad(), held)  # no successor: holds
    # the successor (tag + 1 period) arrives 50 ms after the hold began: ramp from here
    tag2 = T0 + 2 * PERIOD
    _received(v.receive(_joints(2, tag2, _ramp_deg(2))))
    v.advance_to(tag2 - 100_000_000)  # half-way through the remaining 200 ms
    np.testing.assert_allclose(
        v.joint_target_rad(), np.radians(0.5 * (_ramp_deg(1) + _ramp_deg(2))), rtol=0, atol=1e-12
    )
    v.advance_to(tag2)
    np.testing.assert_array_equal(v.joint_target_rad(), np.radians(_ramp_deg(2)))


def test_across_a_lost_command_the_target_keeps_moving_and_never_steps(
    config: VehicleConfig,
) -> None:
    """Command 2 of 0..4 is lost: the target goes straight from command 1 to command 3 (a
    hold and then a jump at command 3's tag would step it by two periods' motion)."""
    v = _vehicle(config)
    for k in (0, 1, 3, 4):
        _received(v.receive(_joints(k, T0 + k * PERIOD, _ramp_deg(k))))
    v.advance_to(T0 + PERIOD)
    for fraction in (0.2, 0.5, 0.96):  # on the 10 ms grid
        v.advance_to(T0 + PERIOD + round(fraction * 2 * PERIOD))
        expected = _ramp_deg(1) + fraction * (_ramp_deg(3) - _ramp_deg(1))
        np.testing.assert_allclose(v.joint_target_rad(), np.radians(expected), rtol=0, atol=1e-12)
    v.advance_to(T0 + 3 * PERIOD)
    np.testing.assert_array_equal(v.joint_target_rad(), np.radians(_ramp_deg(3)))
    # the rate check spans a gap too: 1.6 deg in a 0.5 s gap is 3.2 deg/s, 1.4 deg is not
    faster = _ramp_deg(4) + np.array([1.6, 0, 0, 0, 0, 0])
    _rejected(
        v.receive(_joints(6, T0 + 6 * PERIOD, faster)), RejectReason.OUT_OF_LIMITS, "from seq 4"
    )
    _received(v.receive(_joints(7, T0 + 6 * PERIOD, faster - [0.2, 0, 0, 0, 0, 0])))


# -- refusals -------------------------------------------------------------------------------


def test_a_late_command_is_refused_and_never_executed(config: VehicleConfig) -> None:
    v = _vehicle(config)
    v.advance_to(T0)
    _rejected(v.receive(_joints(0, T0, [0.1] * 6)), RejectReason.LATE, "at or before")
    _rejected(v.receive(_joints(1, T0 - PERIOD, [0.1] * 6)), RejectReason.LATE)
    _received(v.receive(_joints(2, T0 + 10_000_000, [0.0] * 6)))  # one step ahead is in time
    acks, frames = v.advance_to(T0 + 5 * SECOND)
    assert [a.seq for a in acks] == [2]
    np.testing.assert_array_equal(v.joint_target_rad(), np.zeros(6))
    assert all(f.joint_targets_rad == [0.0] * 6 for f in frames)


def test_a_duplicate_seq_has_no_effect(config: VehicleConfig) -> None:
    v = _vehicle(config)
    _received(v.receive(_joints(5, T0, _ramp_deg(1))))
    _rejected(
        v.receive(_joints(6, T0 + PERIOD, [171.0, 0, 0, 0, 0, 0])), RejectReason.OUT_OF_LIMITS
    )
    queued = v.queued
    # the same seq with other joints and another tag, and a refused seq sent again
    _rejected(v.receive(_joints(5, T0 + PERIOD, _ramp_deg(2))), RejectReason.DUPLICATE, "seq 5")
    _rejected(v.receive(_joints(6, T0 + PERIOD, _ramp_deg(2))), RejectReason.DUPLICATE)
    assert v.queued == queued == 1
    acks, _ = v.advance_to(T0 + 2 * SECOND)
    assert [a.seq for a in acks] == [5]
    np.testing.assert_array_equal(v.joint_target_rad(), np.radians(_ramp_deg(1)))
    assert v.last_command_seq == 6


def test_outcome_is_the_latest_ack_of_each_command_received(config: VehicleConfig) -> None:
    """What ``command_query`` answers with: never a duplicate's refusal, always the latest
    stage (received, then executed; or refused on link loss)."""
    v = _vehicle(config)
    assert v.outcome(0) is None  # never received
    _received(v.receive(_joints(0, T0, _ramp_deg(1))))
    _received(v.receive(_joints(1, T0 + PERIOD, _ramp_deg(2))))
    _rejected(v.receive(_joints(2, v.onboard_time_ns, [0.0] * 6)), RejectReason.LATE)
    _rejected(v.receive(_joints(0, T0 + 2 * PERIOD, _ramp_deg(3))), RejectReason.DUPLICATE)
    first = v.outcome(0)
    assert first is not None and first.stage is CommandStage.RECEIVED
    late = v.outcome(2)
    assert late is not None and late.reason is RejectReason.LATE
    acks, _ = v.advance_to(T0)
    assert acks == [v.outcome(0)]  # the executed ack replaced the received one
    executed = v.outcome(0)
    assert executed is not None and executed.stage is CommandStage.EXECUTED
    assert executed.onboard_time_ns == T0
    lost = v.link_lost()
    assert [a.seq for a in lost] == [1] and v.outcome(1) == lost[0]
    assert v.outcome(3) is None


# -- retransmission, capacity and schedule_delete (the windowed uplink) ----------------------


def test_an_identical_copy_gets_the_stored_ack_and_never_executes_twice(
    config: VehicleConfig,
) -> None:
    """The ground sends each command until it is acknowledged: a copy is answered with the
    command's latest acknowledgement ("you already have it") and changes nothing."""
    v = _vehicle(config)
    cmds = [_joints(k, T0 + k * PERIOD, _ramp_deg(k)) for k in range(3)]
    first = v.receive(cmds[0])
    _received(first)
    v.advance_to(EPOCH + SECOND)
    # a copy, re-decoded as it would be from the wire, in an arrival order of its own
    copy = JointCommandMsg.model_validate_json(cmds[0].model_dump_json())
    assert v.receive(copy) == first  # the same ack, with the time of receipt
    _received(v.receive(cmds[2]))
    _received(v.receive(cmds[1]))
    assert v.queued == 3
    acks, _ = v.advance_to(T0)
    assert [a.seq for a in acks] == [0]
    executed = acks[0]
    assert v.receive(copy) == executed  # executed, at its tag
    assert v.queued == 2
    # a refused command's copy gets the refusal again
    late = _joints(3, T0, _ramp_deg(0))
    refused = v.receive(late)
    _rejected(refused, RejectReason.LATE)
    assert v.receive(late) == refused
    # other content under a used seq is a duplicate and stands for nothing
    _rejected(
        v.receive(_joints(0, T0 + 5 * PERIOD, _ramp_deg(1))),
        RejectReason.DUPLICATE,
        "seq 0",
        "other content",
    )
    assert v.outcome(0) == executed
    acks, _ = v.advance_to(T0 + 3 * SECOND)
    assert [a.seq for a in acks] == [1, 2]  # seq 0 executed once
    np.testing.assert_array_equal(v.joint_target_rad(), np.radians(_ramp_deg(2)))
    assert v.receive(cmds[1]).stage is CommandStage.EXECUTED
    assert v.last_command_seq == 3


def test_a_full_schedule_refuses_for_now_and_takes_a_later_copy() -> None:
    v = _vehicle(VehicleConfig(schedule_capacity=3))
    _received(v.receive(_joints(0, T0, _ramp_deg(0))))
    _received(v.receive(_joints(1, T0 + PERIOD, _ramp_deg(1))))
    _received(v.receive(AcsCommandMsg(seq=2, execute_time_ns=T0 + PERIOD, mode="free_drift")))
    late = _joints(3, T0 + 2 * PERIOD, _ramp_deg(2))
    full = v.receive(late)
    _rejected(full, RejectReason.SCHEDULE_FULL, "capacity 3")
    # transient: nothing is recorded, a copy is checked afresh
    assert v.outcome(3) is None and v.queued == 3 and v.last_command_seq == 3
    _rejected(v.receive(late), RejectReason.SCHEDULE_FULL)
    # a command that would be refused anyway is refused for its own reason
    _rejected(v.receive(_joints(4, EPOCH, _ramp_deg(0))), RejectReason.LATE)
    acks, frames = v.advance_to(T0)  # seq 0 executes: room for one
    assert [a.seq for a in acks] == [0]
    buffer = frames[-1].buffer
    assert (buffer.queued, buffer.capacity, buffer.last_executed_seq) == (2, 3, 0)
    assert buffer.next_execute_time_ns == buffer.last_queued_time_ns == T0 + PERIOD
    _received(v.receive(late))
    assert v.receive(late).stage is CommandStage.RECEIVED  # now it is recorded
    _rejected(v.receive(_joints(5, T0 + 3 * PERIOD, _ramp_deg(3))), RejectReason.SCHEDULE_FULL)
    acks, frames = v.advance_to(T0 + 2 * PERIOD)
    assert [a.seq for a in acks] == [1, 2, 3]
    assert frames[-1].buffer.queued == 0 and frames[-1].buffer.last_executed_seq == 3
    np.testing.assert_array_equal(v.joint_target_rad(), np.radians(_ramp_deg(2)))


def test_schedule_delete_removes_the_range_refuses_late_copies_and_the_arm_holds(
    config: VehicleConfig,
) -> None:
    v = _vehicle(config)
    for k in range(12):
        _received(v.receive(_joints(k, T0 + k * PERIOD, _ramp_deg(k))))
    _received(v.receive(AcsCommandMsg(seq=20, execute_time_ns=T0 + 8 * PERIOD, mode="feedback")))
    _received(v.receive(AcsCommandMsg(seq=21, execute_time_ns=T0 + PERIOD, mode="free_drift")))
    # a later plan (seq above max_seq) already loaded: untouched
    _received(v.receive(AcsCommandMsg(seq=100, execute_time_ns=T0 + 9 * PERIOD, mode="feedback")))
    v.advance_to(T0 + 2 * PERIOD + 100_000_000)  # ramping from seq 2 to seq 3
    cut = T0 + 5 * PERIOD
    report = v.delete_schedule(ScheduleDelete(request_id=7, from_time_ns=cut, max_seq=50))
    assert report.stage == "completed" and report.request_id == 7
    assert report.deleted == 8 and report.deleted_ranges == [(5, 11), (20, 20)]
    assert report.executed_after_from == 0 and report.detail is None
    assert report.onboard_time_ns == v.onboard_time_ns
    assert v.queued == 3  # seqs 3, 4 and 100
    deleted = v.outcome(9)
    assert deleted is not None
    _rejected(deleted, RejectReason.CANCELLED, "request 7")
    # copies still in the relay: one received before gets its (new) outcome, one never
    # received is refused by the barrier; outside the range commands are taken as ever
    assert v.receive(_joints(9, T0 + 9 * PERIOD, _ramp_deg(9))) == deleted
    _rejected(v.receive(_joints(12, T0 + 12 * PERIOD, _ramp_deg(12))), RejectReason.CANCELLED, "7")
    barred = v.outcome(12)
    assert barred is not None and barred.reason is RejectReason.CANCELLED
    _received(v.receive(AcsCommandMsg(seq=22, execute_time_ns=T0 + 4 * PERIOD, mode="feedback")))
    # the same request again: the first report, nothing else
    again = v.delete_schedule(ScheduleDelete(request_id=7, from_time_ns=EPOCH, max_seq=10**6))
    assert again == report and v.queued == 4
    # the arm goes on to seq 4 (the last target left) and holds there past the deleted tags
    acks, frames = v.advance_to(T0 + 14 * PERIOD)
    assert [a.seq for a in acks] == [3, 4, 22, 100]
    assert all(a.stage is CommandStage.EXECUTED for a in acks)
    held = np.radians(_ramp_deg(4))
    np.testing.assert_array_equal(v.joint_target_rad(), held)
    after = [f for f in frames if f.generation_time_ns >= T0 + 4 * PERIOD]
    assert len(after) >= 25 and all(f.joint_targets_rad == list(held) for f in after)
    # the later plan's joint commands are not barred
    nxt = T0 + 16 * PERIOD
    _received(v.receive(_joints(101, nxt, _ramp_deg(4) + np.array([0.5, 0, 0, 0, 0, 0]))))
    v.advance_to(T0 + 15 * PERIOD)
    moving = v.joint_target_rad()
    assert moving[0] > held[0]
    # a delete from the past: every queued command of the range, the arm holds mid-ramp
    report = v.delete_schedule(ScheduleDelete(request_id=8, from_time_ns=EPOCH, max_seq=200))
    assert report.deleted == 1 and report.deleted_ranges == [(101, 101)]
    # seqs 0..4, 21, 22 and 100 had executed, all tagged after the epoch
    assert report.executed_after_from == 8
    assert report.detail is not None and "at or before onboard time" in report.detail
    _, frames = v.advance_to(T0 + 20 * PERIOD)
    assert all(f.joint_targets_rad == list(moving) for f in frames)


# -- loss of signal ----------------------------------------------------------------------------


def _sparse(v: Vehicle, n: int) -> list[int]:
    """Joint commands 0..n-1 every 2 s from T0 (0.25 deg/s), all loaded now."""
    tags = [T0 + k * 2 * SECOND for k in range(n)]
    for k, tag in enumerate(tags):
        _received(v.receive(_joints(k, tag, _ramp_deg(k))))
    return tags


def test_los_continue_executes_the_loaded_schedule_through_silence(
    config: VehicleConfig,
) -> None:
    assert config.los_policy == "continue" and config.los_hold_after_s is None
    v = _vehicle(config)
    tags = _sparse(v, 15)  # 30 s of commands, and not a word from the ground after
    acks, _ = v.advance_to(tags[-1] + SECOND)
    assert [a.seq for a in acks] == list(range(15))
    assert all(a.stage is CommandStage.EXECUTED for a in acks)
    np.testing.assert_array_equal(v.joint_target_rad(), np.radians(_ramp_deg(14)))


def test_los_hold_refuses_the_joint_commands_after_the_silence() -> None:
    config = VehicleConfig(los_policy="hold", los_hold_after_s=4.5)
    v = _vehicle(config)
    tags = _sparse(v, 10)  # T0 = 2 s, then 4 s, 6 s, ... 20 s after the epoch
    v.receive(AcsCommandMsg(seq=50, execute_time_ns=EPOCH + 10 * SECOND, mode="free_drift"))
    acks, _ = v.advance_to(EPOCH + 3 * SECOND)
    assert [a.seq for a in acks] == [0]
    v.heard_from_ground()  # e.g. a telemetry_ack at 3 s
    assert v.last_heard_ns == EPOCH + 3 * SECOND
    deadline = EPOCH + 7_500_000_000  # 4.5 s later: between seq 2 (6 s) and seq 3 (8 s)
    acks, frames = v.advance_to(tags[-1] + SECOND)
    assert [(a.seq, a.stage) for a in acks] == [
        (1, CommandStage.EXECUTED),
        (2, CommandStage.EXECUTED),
        *[(k, CommandStage.REJECTED) for k in range(3, 10)],
        (50, CommandStage.EXECUTED),  # attitude commands stay
    ]
    for ack in acks[2:9]:
        _rejected(ack, RejectReason.LINK_LOST, "LOS policy hold", "4.5 s")
        assert ack.onboard_time_ns == deadline and v.outcome(ack.seq) == ack
    assert v.acs_mode is AcsModeName.FREE_DRIFT
    held = np.radians(_ramp_deg(2) + 0.75 * (_ramp_deg(3) - _ramp_deg(2)))
    np.testing.assert_allclose(v.joint_target_rad(), held, rtol=0, atol=1e-12)
    after = [f for f in frames if f.generation_time_ns >= deadline]
    assert len(after) > 100
    assert all(f.joint_targets_rad == after[0].joint_targets_rad for f in after)
    # the ground is heard again: new commands are taken and ramped to from the held target
    tag = v.onboard_time_ns + SECOND
    _received(v.receive(_joints(60, tag, np.degrees(held) + np.array([1.0, 0, 0, 0, 0, 0]))))
    v.advance_to(tag)
    np.testing.assert_allclose(
        v.joint_target_rad(), held + np.radians([1.0, 0, 0, 0, 0, 0]), rtol=0, atol=1e-12
    )


def test_los_hold_waits_while_the_ground_is_heard() -> None:
    v = _vehicle(VehicleConfig(los_policy="hold", los_hold_after_s=2.0))
    tags = _sparse(v, 8)
    executed: list[CommandAck] = []
    t = EPOCH
    while t < tags[-1]:
        t += 1_500_000_000
        executed += v.advance_to(t)[0]
        v.heard_from_ground()  # something from the ground every 1.5 s
    assert [a.seq for a in executed] == list(range(8))
    assert all(a.stage is CommandStage.EXECUTED for a in executed)


def test_limits_and_malformed_commands_are_refused_with_reasons(config: VehicleConfig) -> None:
    v = _vehicle(config)
    _rejected(
        v.receive(_joints(0, T0, [0, 0, 0, 171.0, 0, 0])),
        RejectReason.OUT_OF_LIMITS,
        "joint 4",
        "171.000 deg",
        "limit 170.000 deg",
    )
    _rejected(
        v.receive(_joints(1, T0, [0, -170.5, 0, 0, 0, 0])), RejectReason.OUT_OF_LIMITS, "joint 2"
    )
    _received(v.receive(_joints(2, T0, [0, 0, 0, 0, 0, 0])))
    # 1 deg in one 0.25 s period is 4 deg/s, beyond the 3 deg/s rate limit
    _rejected(
        v.receive(_joints(3, T0 + PERIOD, [0, 1.0, 0, 0, 0, 0])),
        RejectReason.OUT_OF_LIMITS,
        "joint 2",
        "4.000 deg/s",
        "limit 3.000 deg/s",
    )
    # ... also measured to the queued command after it
    _received(v.receive(_joints(4, T0 + 2 * PERIOD, [0, 0, 0, 0, 0, 1.0])))  # 2 deg/s
    _rejected(
        v.receive(_joints(5, T0 + PERIOD, [0, 0, 0, 0, 0, 0.0])),
        RejectReason.OUT_OF_LIMITS,
        "joint 6",
        "to seq 4",
    )
    # tags off the 10 ms grid, an attitude target that is not a rotation, a taken tag
    _rejected(
        v.receive(_joints(6, T0 + 3 * PERIOD + 5_000_000, [0] * 6)),
        RejectReason.MALFORMED,
        "off the onboard 10 ms step grid",
    )
    _rejected(
        v.receive(
            AcsCommandMsg(
                seq=7,
                execute_time_ns=T0,
                mode="feedback",
                target_quat_orbit_from_base_xyzw=[0.0, 0.0, 0.0, 1.01],
            )
        ),
        RejectReason.MALFORMED,
        "norm 1.01",
    )
    _rejected(v.receive(_joints(8, T0, [0] * 6)), RejectReason.MALFORMED, "seq 2")
    # a quaternion within the tolerance is accepted and stored normalised
    _received(
        v.receive(
            AcsCommandMsg(
                seq=9,
                execute_time_ns=T0,
                mode="feedback",
                target_quat_orbit_from_base_xyzw=[0.0, 0.0, 0.0, 1.0005],
            )
        )
    )
    assert v.queued == 3 and v.last_command_seq == 9
    acks, _ = v.advance_to(T0 + SECOND)
    assert sorted(a.seq for a in acks) == [2, 4, 9]
    np.testing.assert_allclose(v.acs_target_quat_xyzw, IDENTITY, rtol=0, atol=1e-15)


# -- holding and the safe state --------------------------------------------------------------


def test_the_arm_holds_still_when_commands_stop(config: VehicleConfig) -> None:
    v = _vehicle(config)
    for k in range(21):
        v.receive(_joints(k, T0 + k * PERIOD, _ramp_deg(k)))
    last_tag = T0 + 20 * PERIOD
    v.advance_to(last_tag)
    final = np.radians(_ramp_deg(20))
    # servo lag at 2 deg/s: the joint trails its target by a few tenths of a degree (SPEC 6)
    lag_deg = np.degrees(np.max(np.abs(v.true_state().joints_rad - final)))
    assert 0.2 < lag_deg < 1.0
    _, frames = v.advance_to(last_tag + 60 * SECOND)
    assert all(f.joint_targets_rad == list(final) for f in frames)  # the target is constant
    settled = v.true_state().joints_rad
    # servo settling (damping ratio 0.9, 6 rad/s): within 1e-4 deg after 5 s, measured 4e-5
    assert np.degrees(np.max(np.abs(settled - final))) < 1e-4
    v.advance_to(last_tag + 120 * SECOND)
    drift_deg = np.degrees(np.max(np.abs(v.true_state().joints_rad - settled)))
    assert drift_deg < 1e-4  # no drift while holding (measured 3e-5 deg)


def test_link_loss_refuses_queued_joint_commands_and_holds_the_arm(
    config: VehicleConfig,
) -> None:
    """The safe state the ``hold`` LOS policy enters, here at once (``link_lost``)."""
    v = _vehicle(config)
    for k in range(20):
        v.receive(_joints(k, T0 + k * PERIOD, _ramp_deg(k)))
    acs_tag = T0 + 10 * SECOND
    v.receive(AcsCommandMsg(seq=50, execute_time_ns=acs_tag, mode="feedback", feedforward=True))
    v.advance_to(T0 + 5 * PERIOD + 100_000_000)  # mid-ramp between commands 5 and 6
    holding = v.joint_target_rad()
    assert np.all(holding[[0, 3]] != np.radians(_ramp_deg(5))[[0, 3]])  # it was moving
    acks = v.link_lost()
    assert [a.seq for a in acks] == list(range(6, 20))
    assert all(a.reason is RejectReason.LINK_LOST for a in acks)
    assert all(a.onboard_time_ns == v.onboard_time_ns for a in acks)
    assert v.queued == 1  # the attitude command stays queued
    executed, frames = v.advance_to(acs_tag + SECOND)
    assert [a.seq for a in executed] == [50]  # attitude control carries on
    assert v.acs_mode is AcsModeName.FEEDBACK and v.acs_feedforward
    assert all(f.joint_targets_rad == list(holding) for f in frames)
    # the next command is checked against the held target: a jump is out of limits ...
    tag = v.onboard_time_ns + PERIOD
    _rejected(
        v.receive(_joints(60, tag, _ramp_deg(19))), RejectReason.OUT_OF_LIMITS, "current target"
    )
    # ... and one that starts from it is ramped to from there
    resume = np.degrees(holding) + np.array([0.5, 0, 0, 0, 0, 0])
    _received(v.receive(_joints(61, tag, resume)))
    v.advance_to(tag)
    np.testing.assert_allclose(v.joint_target_rad(), np.radians(resume), rtol=0, atol=1e-15)


# -- truth simulation and attitude control ---------------------------------------------------


def test_free_drift_conserves_momentum() -> None:
    config = VehicleConfig(
        sim=SimConfig(gravity_gradient=False), initial_acs_mode=AcsModeName.FREE_DRIFT
    )
    v = _vehicle(config)
    ws = DynamicsWorkspace(config.model)
    rate_deg = np.array([2.0, -1.5, 2.5, 1.0, -2.0, 2.8])
    for k in range(41):  # 10 s on every joint, then a hold
        v.receive(_joints(k, EPOCH + SECOND + k * PERIOD, rate_deg * 0.25 * k))
    angular, linear, arm = [], [], []
    for i in range(1, 301):
        v.advance_to(EPOCH + i * 100_000_000)
        state = v.true_state()
        q = ws.evaluate(state)
        angular.append(q.angular_momentum_nms)
        linear.append(q.linear_momentum_nms)
        arm.append(q.H_bm_tilde @ state.joint_rates_radps)
    # RK4 at 10 ms through the servo transients: measured 1.3e-8 N m s and 5e-9 kg m/s
    # against an arm momentum of 2.8 N m s
    assert np.max(np.abs(arm)) > 1.0
    assert np.max(np.abs(angular)) < 1e-7
    assert np.max(np.abs(linear)) < 1e-7
    assert np.max(np.abs(v.wheel_momentum_nms())) < 1e-9  # no wheel torque (measured 3e-13)
    assert (
        np.degrees(Rotation.from_quat(v.true_state().quat_orbit_from_base_xyzw).magnitude()) > 0.1
    )


def test_feedback_returns_a_disturbed_attitude_to_its_target() -> None:
    tilt = Rotation.from_euler("ZYX", [0.2, -0.5, 0.3], degrees=True).as_quat()
    v = _vehicle(VehicleConfig(initial_quat_orbit_from_base_xyzw=tuple(tilt)))
    offset = Rotation.from_euler("ZYX", [0.0, 0.25, 0.0], degrees=True)
    v.receive(
        AcsCommandMsg(
            seq=0,
            execute_time_ns=EPOCH + 200 * SECOND,
            mode="feedback",
            target_quat_orbit_from_base_xyzw=list(offset.as_quat()),
        )
    )
    band_deg = math.degrees(v.gains.dead_band_rad)
    errors = []  # the largest axis's attitude error (the law's dead band is per axis)
    for i in range(1, 201):
        v.advance_to(EPOCH + i * SECOND)
        rotvec = Rotation.from_quat(v.true_state().quat_orbit_from_base_xyzw).as_rotvec()
        errors.append(np.max(np.abs(rotvec)))
    errors_deg = np.degrees(errors)
    assert errors_deg[0] > 0.4
    # the calibrated law (wn 0.030 rad/s, zeta 0.55, an 11 s rate filter, a 0.035 deg dead
    # band per axis): measured 0.034 deg at 80 s, 0.022 at 100 s; then gravity gradient
    # turns the base inside the dead band, where only the rate term acts, until the
    # proportional term holds it at the band's edge: 0.030 deg at 120 s, 0.043 at 180 s, at
    # most 0.046 (sensor noise moves it a few 1e-4 deg)
    assert errors_deg[99] < 0.03
    assert np.all(errors_deg[99:] < band_deg + 0.015)
    assert np.max(np.abs(v.wheel_momentum_nms())) > 0.1  # the wheels did the work
    # a new target (the offset destination of experiment 3c) is followed just as well
    later = []
    for i in range(201, 401):
        v.advance_to(EPOCH + i * SECOND)
        reached = Rotation.from_quat(v.true_state().quat_orbit_from_base_xyzw)
        later.append(np.max(np.abs((offset.inv() * reached).as_rotvec())))
    later_deg = np.degrees(later)
    # measured: 0.020 deg 100 s after the switch, at most 0.030 from then on
    assert np.all(later_deg[99:] < band_deg + 0.015)
    assert later_deg[0] > 0.2  # it was a real move: 0.25 deg


# -- telemetry --------------------------------------------------------------------------------


def test_telemetry_every_period_with_consecutive_seqs_and_sample_times(
    config: VehicleConfig,
) -> None:
    v = _vehicle(config)
    v.receive(_joints(0, T0, [0.2] * 6))
    frames = []
    rng = np.random.default_rng(1)
    t = EPOCH
    while t < EPOCH + 30 * SECOND:  # irregular, off-grid advances
        t += int(rng.integers(1, 700_000_000))
        frames += v.advance_to(t)[1]
    n = len(frames)
    assert [f.seq for f in frames] == list(range(n))
    assert [f.generation_time_ns for f in frames] == [EPOCH + k * 100_000_000 for k in range(n)]
    assert n == v.next_telemetry_seq and frames[-1].generation_time_ns <= t
    assert frames[0].buffer.queued == 1 and frames[0].buffer.next_execute_time_ns == T0
    assert frames[0].buffer.last_queued_time_ns == T0
    assert frames[0].buffer.capacity == DEFAULT_SCHEDULE_CAPACITY
    assert frames[0].buffer.last_executed_seq == -1
    assert frames[-1].buffer.queued == 0 and frames[-1].buffer.next_execute_time_ns is None
    assert frames[-1].buffer.last_queued_time_ns is None
    assert frames[-1].buffer.last_executed_seq == 0
    assert frames[-1].acs_mode is AcsModeName.FEEDBACK and frames[-1].acs_target_quat_xyzw == (
        IDENTITY
    )
    # the same seed gives the same frames however the time is cut (to rounding: the
    # simulator turns the gravity-gradient torque into the orbit frame at each of its calls)
    again = _vehicle(config)
    again.receive(_joints(0, T0, [0.2] * 6))
    assert _frames_close(again.advance_to(t)[1], frames, atol=1e-9)
    other = _vehicle(config, seed=8)
    other.receive(_joints(0, T0, [0.2] * 6))
    assert not _frames_close(other.advance_to(t)[1], frames, atol=1e-6)


def _frames_close(a: list[TelemetryFrame], b: list[TelemetryFrame], *, atol: float) -> bool:
    """Equal frames, floats to ``atol`` (exact when the seeds differ would be a bug)."""
    if len(a) != len(b):
        return False
    for x, y in zip(a, b, strict=True):
        dx, dy = x.model_dump(), y.model_dump()
        for key, value in dx.items():
            if isinstance(value, list):
                if not np.allclose(value, dy[key], rtol=0, atol=atol):
                    return False
            elif value != dy[key]:
                return False
    return True


def test_telemetry_noise_has_the_configured_statistics() -> None:
    noise = SensorNoise(
        attitude_rad=math.radians(0.01), rate_radps=math.radians(0.001), joint_rad=1e-4
    )
    v = _vehicle(VehicleConfig(noise=noise), seed=11)
    v.advance_to(EPOCH)  # the frame at the epoch; then one frame per call
    d_att, d_rate, d_joint = [], [], []
    for k in range(1, 1001):
        _, frames = v.advance_to(EPOCH + k * 100_000_000)
        (frame,) = frames
        truth = v.true_state()
        measured = Rotation.from_quat(frame.quat_orbit_from_base_xyzw)
        d_att.append(
            (Rotation.from_quat(truth.quat_orbit_from_base_xyzw).inv() * measured).as_rotvec()
        )
        true_rate = truth.rot_orbit_from_base.T @ truth.omega_base_orbit_radps
        d_rate.append(np.array(frame.omega_base_in_base_radps) - true_rate)
        d_joint.append(np.array(frame.joints_rad) - truth.joints_rad)
    # 3000 (attitude, rate) and 6000 (joint) samples: the sample sigma is within 5 % (about
    # four standard errors) and the mean within 4 standard errors of zero
    for samples, sigma in (
        (d_att, noise.attitude_rad),
        (d_rate, noise.rate_radps),
        (d_joint, noise.joint_rad),
    ):
        values = np.ravel(samples)
        assert np.std(values) == pytest.approx(sigma, rel=0.05)
        assert abs(np.mean(values)) < 4 * sigma / math.sqrt(values.size)


def test_configuration_is_checked() -> None:
    with pytest.raises(VehicleError, match="slower than 4 Hz"):
        VehicleConfig(telemetry_period_s=0.5)
    with pytest.raises(VehicleError, match="multiple of the 10 ms"):
        VehicleConfig(control_period_s=0.015)
    with pytest.raises(VehicleError, match="initial joints"):
        VehicleConfig(initial_joints_rad=(0, 0, 0, 3.1, 0, 0))
    with pytest.raises(ValueError, match="must be finite"):
        SensorNoise(joint_rad=-1.0)
    with pytest.raises(VehicleError, match="schedule_capacity"):
        VehicleConfig(schedule_capacity=0)
    with pytest.raises(VehicleError, match="'continue' or 'hold'"):
        VehicleConfig(los_policy="panic")  # type: ignore[arg-type]
    with pytest.raises(VehicleError, match="needs los_hold_after_s > 0"):
        VehicleConfig(los_policy="hold")
    with pytest.raises(VehicleError, match="needs los_hold_after_s > 0"):
        VehicleConfig(los_policy="hold", los_hold_after_s=0.0)
    with pytest.raises(VehicleError, match="only with los_policy 'hold'"):
        VehicleConfig(los_hold_after_s=30.0)


# -- calibration against the flight (docs/spacecraft.md) -------------------------------------


@pytest.fixture(scope="module")
def ws() -> DynamicsWorkspace:
    return DynamicsWorkspace(default_model())


@pytest.fixture(scope="module")
def calibration(ws: DynamicsWorkspace) -> dict[str, Plan]:
    """The plans calibration flies (spacecraft._calibration.calibration_plans), planned once
    for the module's flights of them (read only)."""
    from spacecraft._calibration import calibration_plans

    return calibration_plans(ws)


def test_plans_become_uplink_messages_in_tag_order(ws: DynamicsWorkspace) -> None:
    from planner.experiments import PtpParams, plan_ptp

    plan = plan_ptp(ws, PtpParams(goal_joints_deg=(2.0, 0, 0, 0, 0, 0), settle_s=1.0))
    msgs = plan_messages(plan, epoch_ns=EPOCH, first_seq=10)
    assert [m.seq for m in msgs] == list(range(10, 10 + len(msgs)))
    assert isinstance(msgs[0], AcsCommandMsg) and msgs[0].execute_time_ns == EPOCH + SECOND
    joints = [m for m in msgs if isinstance(m, JointCommandMsg)]
    assert [m.execute_time_ns for m in joints] == [
        EPOCH + SECOND + round(t * 1e9) for t in plan.command_times_s
    ]


@pytest.mark.slow
def test_ptp_settles_in_about_100_s_and_gjm_pitches_the_base_as_in_flight(
    ws: DynamicsWorkspace, config: VehicleConfig, calibration: dict[str, Plan]
) -> None:
    from planner.gjm import plan_gjm
    from spacecraft._calibration import ptp_settling_s

    ptp = calibration["ptp"]  # a 360 s wait: the final value is the one held
    flight = fly_plan(ptp, config)
    assert flight.rejected == 0
    # flight: about 100 s to settle (70 to 130 s, the report's criterion: within 0.05 deg of
    # the attitude the loop holds); ours 100.5 s with the calibrated law. The absolute return
    # within 0.05 deg of nominal takes a little longer (108 s): the base comes to rest
    # inside the law's 0.035 deg dead band, pushed by gravity gradient (docs/spacecraft.md).
    assert 70.0 < ptp_settling_s(flight, ptp) < 130.0
    # the feedback pulled the base back: below the 1.3 deg free drift would leave (0.93)
    assert 0.6 < np.max(flight.attitude_deg) < 1.1

    gjm = plan_gjm(ws)
    flight = fly_plan(gjm, config)
    assert flight.rejected == 0
    pitch = flight.pitch_deg - flight.pitch_deg[0]
    # flight: about -0.6 deg (ours -0.607, with lagging servos and gravity gradient)
    assert np.min(pitch) == pytest.approx(-0.6, abs=0.05)


@pytest.mark.slow
def test_the_attitude_modes_differ_on_the_coordination_motion_as_in_flight(
    config: VehicleConfig, calibration: dict[str, Plan]
) -> None:
    """Experiment 3 (paper 3.5, Fig. 9) flown through the vehicle, all three variants, as the
    demo pass schedules them (one back-and-forth motion, 120 s settle) and measured as the
    report does (spacecraft._calibration.coordination_metrics)."""
    plan = calibration["coordination"]
    flight = fly_plan(plan, config)
    assert flight.rejected == 0
    a, b, c = (coordination_metrics(flight, plan, label) for label in ("(a)", "(b)", "(c)"))
    # every variant starts at rest, as in flight (ours within 0.036 deg: inside the dead band)
    assert all(abs(m["start_pitch_deg"]) < 0.05 for m in (a, b, c))
    # (a) feedback: a dip, a positive swing, then back (flight -0.5 to +0.4 deg, +-0.15;
    # ours -0.351 to +0.502 from rest, -0.36 to +0.50 in the demo pass)
    assert -0.65 < a["pitch_min_deg"] < -0.35 and 0.25 < a["pitch_max_deg"] < 0.55
    # (b) feedforward: a faster first response, within -0.3 deg as in flight (ours -0.257) ...
    assert b["first_dip_deg"] > -0.3 and b["first_dip_deg"] > a["first_dip_deg"] + 0.05
    # ... then the recovery adds to the reversal's reaction: the strongest positive
    # overshoot (ours 0.199 deg above the next)
    assert b["pitch_max_deg"] > max(a["pitch_max_deg"], c["pitch_max_deg"]) + 0.05
    # (c) offset destination, held over the whole motion: the smallest range, as in flight
    # (ours 0.293 deg below the next) and the fastest settling, back within 0.05 deg of the
    # origin: (c) 99.7 s, (a) 112.0 s, (b) 114.7 s
    assert c["pitch_range_deg"] + 0.1 < a["pitch_range_deg"] < b["pitch_range_deg"]
    assert a["settled"] and b["settled"] and c["settled"]
    assert c["settling_time_s"] + 8.0 < min(a["settling_time_s"], b["settling_time_s"])


def test_default_vehicle_uses_gravity_gradient_and_the_calibrated_wheels(
    config: VehicleConfig,
) -> None:
    assert config.sim.gravity_gradient
    v = _vehicle(config)
    inertia = np.diag(DynamicsWorkspace(config.model).momentum_blocks(np.zeros(6))[0])
    # the calibrated law: PD on an 11 s filtered rate, wn 0.030 rad/s, zeta 0.55, a 0.035 deg
    # dead band
    np.testing.assert_allclose(v.gains.kp_nm_per_rad, inertia * 0.030**2, rtol=1e-12)
    np.testing.assert_allclose(v.gains.kd_nms_per_rad, 2 * 0.55 * inertia * 0.030, rtol=1e-12)
    assert v.gains.rate_filter_tau_s == 11.0 and not v.gains.has_integral
    assert v.gains.dead_band_rad == pytest.approx(math.radians(0.035), rel=1e-12)


@pytest.mark.slow
def test_a_vehicle_configured_with_a_law_flies_what_the_plan_predicted_with_it(
    ws: DynamicsWorkspace, config: VehicleConfig, tmp_path: Path
) -> None:
    """The law's parameters flow from one TOML file to both the planner's prediction and
    the vehicle: a 10 s rate-estimate lag, wn 0.03 rad/s, zeta 0.85, no dead band and a
    small integral (not the default law)."""
    from planner.attitude_control import default_acs_gains
    from planner.description import load_acs_config
    from planner.experiments import PtpParams, plan_ptp

    path = tmp_path / "acs.toml"
    path.write_text(
        "[acs]\nbandwidth_radps = 0.03\ndamping_ratio = 0.85\nrate_filter_tau_s = 10.0\n"
        "integral_time_s = 200\ndead_band_deg = 0.0\n"
    )
    gains = load_acs_config(ws, path)
    expected = default_acs_gains(
        ws,
        bandwidth_radps=0.03,
        damping_ratio=0.85,
        rate_filter_tau_s=10.0,
        integral_time_s=200.0,
        dead_band_rad=0.0,
    )
    np.testing.assert_array_equal(gains.ki_nm_per_rad_s, expected.ki_nm_per_rad_s)
    # 30 s of settling, not the default 120: both largest differences fall in the motion
    # (measured at 19.0 s and 51.5 s of its 53.75 s, the same with 120 s of settling)
    plan = plan_ptp(ws, PtpParams(settle_s=30.0), gains=gains)
    predicted = np.degrees(plan.prediction.rpy_base_rad[:, 1])
    peak = np.max(np.abs(predicted))
    errors = []
    for acs_gains in (gains, None):
        flight = fly_plan(plan, replace(config, acs_gains=acs_gains))
        assert flight.rejected == 0
        flown = np.interp(plan.command_times_s, flight.t_s, flight.pitch_deg)
        errors.append(np.max(np.abs(predicted - flown)))
    # measured: 0.012 deg (1.7 % of the 0.70 deg peak: servo lag, the 10 Hz law, noise and
    # gravity gradient, none of them in the prediction); the default law's vehicle is 0.23 off
    assert errors[0] < 0.03 * peak
    assert errors[1] > 0.15
