"""The frame evaluator (telemetry.limits): each quantity's value on constructed frames against a
hand computation, the bands' transitions it reports, and a batch equal to frames one by one."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from planner.attitude_control import attitude_error_rad
from planner.clearance_watch import ClearanceWatch
from planner.description import default_robot
from planner.limits import DEFAULT_LIMITS, Limits, Severity
from planner.robot import RobotDescription
from telemetry.limits import (
    FrameEvaluator,
    Reading,
    attitude_error_deg,
    for_description,
    interpolated_commands,
    link_readings,
)
from telemetry.wire import AcsModeName, BufferState, TelemetryFrame

LIMITS_RAD = np.radians(np.tile([-170.0, 170.0], (6, 1)))
SPIN = np.array([0.15, 0.15, 0.3])
MOMENTUM = np.array([20.0, 20.0, 10.0])


@pytest.fixture(scope="module")
def ets7() -> RobotDescription:
    return default_robot()


def frame(
    seq: int = 0,
    *,
    joints_deg: list[float] | None = None,
    targets_deg: list[float] | None = None,
    quat: list[float] | None = None,
    target_quat: list[float] | None = None,
    omega: list[float] | None = None,
    wheels: list[float] | None = None,
    queued: int = 0,
    capacity: int | None = None,
) -> TelemetryFrame:
    joints = np.radians(joints_deg if joints_deg is not None else [0.0] * 6)
    targets = np.radians(targets_deg) if targets_deg is not None else joints
    speeds = wheels if wheels is not None else [0.0, 0.0, 0.0]
    return TelemetryFrame(
        seq=seq,
        generation_time_ns=1_000_000_000 + 100_000_000 * seq,
        joints_rad=joints.tolist(),
        joint_targets_rad=np.asarray(targets).tolist(),
        quat_orbit_from_base_xyzw=quat or [0.0, 0.0, 0.0, 1.0],
        omega_base_in_base_radps=omega or [0.0, 0.0, 0.0],
        wheel_speeds_radps=speeds,
        wheel_momentum_nms=[s * i for s, i in zip(speeds, SPIN, strict=True)],
        acs_mode=AcsModeName.FEEDBACK,
        acs_target_quat_xyzw=target_quat or [0.0, 0.0, 0.0, 1.0],
        acs_feedforward=False,
        buffer=BufferState(queued=queued, capacity=capacity),
    )


def evaluator(limits: Limits = DEFAULT_LIMITS, **kwargs: object) -> FrameEvaluator:
    return FrameEvaluator(
        limits,
        n_joints=6,
        joint_limits_rad=LIMITS_RAD,
        wheel_spin_inertia_kgm2=SPIN,
        wheel_momentum_limit_nms=MOMENTUM,
        **kwargs,  # type: ignore[arg-type]
    )


# --- values against a hand computation ------------------------------------------------------


def test_a_known_rotation_gives_its_attitude_error() -> None:
    target = Rotation.from_euler("x", 30.0, degrees=True)
    off = Rotation.from_euler("z", 1.7, degrees=True)
    measured = target * off  # the base 1.7 deg about its z from the target
    q = measured.as_quat().tolist()
    minus_q = (-measured.as_quat()).tolist()  # the same attitude, the other sign
    values = evaluator().values(
        [frame(0, quat=q, target_quat=target.as_quat().tolist()), frame(1, quat=minus_q)]
    )
    np.testing.assert_allclose(values["attitude_error_deg"][0], [0.0, 0.0, 1.7], atol=1e-9)
    # against the identity target: the whole rotation (30 deg about x, then 1.7 about z)
    expected = np.abs(np.degrees(measured.as_rotvec()))
    np.testing.assert_allclose(values["attitude_error_deg"][1], expected, atol=1e-9)


def test_the_vectorised_attitude_error_is_the_control_law_s() -> None:
    rng = np.random.default_rng(2)
    q = Rotation.random(200, random_state=rng).as_quat()
    t = Rotation.random(200, random_state=rng).as_quat()
    q[:5] = t[:5]  # no error at all
    q[5:10] = -t[5:10]  # no error, the other sign
    got = attitude_error_deg(q, t)
    expected = np.degrees([attitude_error_rad(a, b) for a, b in zip(q, t, strict=True)])
    np.testing.assert_allclose(got, expected, atol=1e-9)
    assert np.all(np.linalg.norm(got, axis=1) <= 180.0 + 1e-9)  # the short way round


def test_rates_wheels_joints_and_the_schedule() -> None:
    f = frame(
        joints_deg=[160.0, -165.0, 0.0, 10.0, 0.0, 0.0],
        targets_deg=[161.5, -165.0, 0.0, 7.0, 0.0, 0.0],
        omega=[0.001, 0.002, -0.002],
        wheels=[50.0, -20.0, 10.0],
        queued=512,
    )
    v = evaluator().values([f])
    assert v["body_rate_degps"][0, 0] == pytest.approx(math.degrees(0.003))
    np.testing.assert_allclose(
        v["wheel_momentum_fraction"][0], [50 * 0.15 / 20, 20 * 0.15 / 20, 10 * 0.3 / 10]
    )
    np.testing.assert_allclose(v["wheel_speed_rpm"][0], np.array([50, 20, 10]) * 60 / (2 * np.pi))
    np.testing.assert_allclose(v["joint_tracking_error_deg"][0], [1.5, 0, 0, 3.0, 0, 0], atol=1e-9)
    np.testing.assert_allclose(
        v["joint_limit_distance_deg"][0], [10.0, 5.0, 170.0, 160.0, 170.0, 170.0], atol=1e-9
    )
    assert v["schedule_occupancy"][0, 0] == 0.5  # of the wire's default 1024
    assert evaluator().values([frame(queued=30, capacity=40)])["schedule_occupancy"][0, 0] == 0.75
    assert np.isnan(v["clearance_m"][0, 0])  # no watch: never in a band


def test_tracking_error_is_against_the_plan_and_falls_back_to_the_frame() -> None:
    # the plan: joint 2 from 0 to 10 deg between t = 1.0 s and t = 2.0 s
    tags = np.array([1_000_000_000, 2_000_000_000], dtype=np.int64)
    commanded = interpolated_commands(
        tags, np.radians(np.array([[0.0] * 6, [0.0, 10.0, 0.0, 0.0, 0.0, 0.0]]))
    )
    frames = [
        frame(0, joints_deg=[0, 0, 0, 0, 0, 0], targets_deg=[0, 4, 0, 0, 0, 0]),  # t = 1.0
        frame(5, joints_deg=[0, 3, 0, 0, 0, 0], targets_deg=[0, 9, 0, 0, 0, 0]),  # t = 1.5
        frame(10, joints_deg=[0, 10, 0, 0, 0, 0], targets_deg=[0, 10, 0, 0, 0, 0]),  # t = 2.0
        frame(11, joints_deg=[0, 10, 0, 0, 0, 0], targets_deg=[0, 12, 0, 0, 0, 0]),  # after
    ]
    error = evaluator(commanded=commanded).values(frames)["joint_tracking_error_deg"][:, 1]
    np.testing.assert_allclose(error, [0.0, 2.0, 0.0, 2.0], atol=1e-9)
    alone = evaluator().values(frames)["joint_tracking_error_deg"][:, 1]
    np.testing.assert_allclose(alone, [4.0, 6.0, 0.0, 2.0], atol=1e-9)


def test_interpolated_commands() -> None:
    fn = interpolated_commands(
        np.array([0, 250, 500]), np.array([[0.0, 1.0], [1.0, 1.0], [3.0, 0.0]])
    )
    out = fn(np.array([-1, 0, 125, 375, 500, 501]))
    assert out is not None
    assert np.isnan(out[0]).all() and np.isnan(out[-1]).all()
    np.testing.assert_allclose(out[1:-1], [[0.0, 1.0], [0.5, 1.0], [2.0, 0.5], [3.0, 0.0]])
    one = interpolated_commands(np.array([100]), np.array([[1.0, 2.0]]))(np.array([99, 100, 101]))
    assert one is not None and np.isnan(one[[0, 2]]).all()
    np.testing.assert_array_equal(one[1], [1.0, 2.0])
    with pytest.raises(ValueError, match="strictly increasing"):
        interpolated_commands(np.array([0, 0]), np.zeros((2, 6)))


def test_clearance_comes_from_the_watch(ets7: RobotDescription) -> None:
    ev = for_description(ets7)
    watch = DEFAULT_LIMITS["clearance_m"].least
    assert ev.clearance is not None and ev.clearance.threshold_m == watch
    b = np.degrees(ets7.pose_joints_rad("B")).tolist()
    v = ev.values([frame(0), frame(1, joints_deg=b)])["clearance_m"][:, 0]
    exact = ClearanceWatch(ets7, math.inf)
    # far from every band the value may be a lower bound, never above the exact clearance
    assert v[0] == pytest.approx(exact.exact_m(np.zeros(6)), abs=1e-12)
    assert watch < v[1] <= exact.exact_m(np.radians(b)) + 1e-12


# --- bands and transitions ------------------------------------------------------------------


def _tracking(seq: int, error_deg: float) -> TelemetryFrame:
    return frame(seq, targets_deg=[0.0, 0.0, error_deg, 0.0, 0.0, 0.0])


def test_evaluate_reports_bands_and_every_change_back_to_none() -> None:
    ev = evaluator()
    watch, warning, critical = (t for _, t in DEFAULT_LIMITS["joint_tracking_error_deg"].thresholds)
    between = (warning + critical) / 2
    errors = [0.0, (watch + warning) / 2, between, between + 0.01, 1.0, 0.5]
    readings = ev.evaluate([_tracking(i, e) for i, e in enumerate(errors)])
    assert [(r.frame_seq, r.severity) for r in readings] == [
        (1, Severity.WATCH),
        (2, Severity.WARNING),
        (3, Severity.WARNING),
        (4, None),  # the clear
    ]
    assert {(r.quantity, r.channel) for r in readings} == {("joint_tracking_error_deg", "joint3")}
    assert readings[2].value == pytest.approx(between + 0.01)
    assert readings[2].generation_time_ns == 1_300_000_000
    # the previous band carries over from one batch to the next
    assert ev.evaluate([_tracking(6, 0.1)]) == []
    assert [r.severity for r in ev.evaluate([_tracking(7, 6.0)])] == [Severity.CRITICAL]
    assert [r.severity for r in ev.evaluate([_tracking(8, 0.0)])] == [None]
    assert ev.evaluate([]) == []


def test_a_batch_reads_as_its_frames_one_by_one() -> None:
    rng = np.random.default_rng(4)
    frames = []
    for i in range(120):
        rot = Rotation.from_rotvec(rng.normal(0.0, 0.03, 3))
        frames.append(
            frame(
                i,
                joints_deg=rng.uniform(-169.0, 169.0, 6).tolist(),
                targets_deg=None,
                quat=rot.as_quat().tolist(),
                omega=rng.normal(0.0, 0.002, 3).tolist(),
                wheels=rng.normal(0.0, 60.0, 3).tolist(),
                queued=int(rng.integers(0, 1024)),
            )
        )
    batch = evaluator().evaluate(frames)
    one = evaluator()
    singles = [r for f in frames for r in one.evaluate([f])]
    assert batch == singles
    assert len({r.quantity for r in batch}) >= 5  # many quantities went in and out of bands
    assert any(r.severity is None for r in batch)
    # within a frame, in the catalogue's order
    seq0 = [r.quantity for r in batch if r.frame_seq == batch[0].frame_seq]
    order = list(DEFAULT_LIMITS.bands)
    assert seq0 == sorted(seq0, key=order.index)


def test_a_frame_of_another_robot_is_refused() -> None:
    seven = frame(0).model_copy(update={"joints_rad": [0.0] * 7, "joint_targets_rad": [0.0] * 7})
    with pytest.raises(ValueError, match="6 joints and 3 wheels"):
        evaluator().values([seven])


def test_link_readings() -> None:
    readings = link_readings(DEFAULT_LIMITS, frames_behind=5, frame_age_s=10_000.0)
    assert [(r.quantity, r.severity) for r in readings] == [
        ("frames_behind", None),
        ("frame_age_s", DEFAULT_LIMITS["frame_age_s"].thresholds[-1][0]),
    ]
    assert link_readings(DEFAULT_LIMITS, frames_behind=None, frame_age_s=None) == []
    assert isinstance(readings[0], Reading) and readings[0].channel == ""
