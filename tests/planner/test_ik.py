"""Inverse kinematics reaches the paper's poses and ranks what it finds."""

from __future__ import annotations

import numpy as np
import pytest

from planner.dynamics import DynamicsWorkspace
from planner.errors import DidNotConverge, InfeasibleGoal, InvalidInput
from planner.frames import matrix_from_rpy, rotation_angle_rad
from planner.ik import solve_ik
from planner.state import State

POSE_B_POS_ROBOT_M = np.array([1.170, 0.407, 0.490])
POSE_B_RPY_DEG = np.array([0.0, 90.0, -37.0])
SPEC_JOINTS_B_DEG = np.array([31.6, 21.4, -8.8, 77.4, 0.0, 68.6])


def test_ik_reaches_pose_b_at_the_spec_solution(workspace: DynamicsWorkspace) -> None:
    rot = matrix_from_rpy(np.radians(POSE_B_RPY_DEG))
    solutions = solve_ik(workspace, POSE_B_POS_ROBOT_M, rot)
    best = solutions[0]
    hand = workspace.hand_pose(State(joints_rad=best.joints_rad))
    np.testing.assert_allclose(hand.pos_robot_m, POSE_B_POS_ROBOT_M, atol=1e-9)
    assert rotation_angle_rad(hand.rot_robot_from_hand @ rot.T) < 1e-9
    # SPEC 7 gives B's joints to 0.1 deg.
    np.testing.assert_allclose(np.degrees(best.joints_rad), SPEC_JOINTS_B_DEG, atol=0.06)


def test_ik_ranks_several_solutions_by_distance_from_the_reference(
    workspace: DynamicsWorkspace,
) -> None:
    truth = np.radians([20.0, 30.0, -40.0, 30.0, 20.0, 10.0])
    hand = workspace.hand_pose(State(joints_rad=truth))
    solutions = solve_ik(workspace, hand.pos_robot_m, hand.rot_robot_from_hand)
    assert len(solutions) >= 2  # elbow-up and elbow-down both lie within +-170 deg here
    distances = [s.distance_from_reference_rad for s in solutions]
    assert distances == sorted(distances)
    assert any(np.allclose(s.joints_rad, truth, atol=1e-8) for s in solutions)
    for s in solutions:
        reached = workspace.hand_pose(State(joints_rad=s.joints_rad))
        np.testing.assert_allclose(reached.pos_robot_m, hand.pos_robot_m, atol=1e-9)
        assert np.all(np.abs(s.joints_rad) <= np.radians(170.0))
        assert s.limit_margin_rad >= 0.0


def test_ik_prefers_the_solution_nearest_the_reference(workspace: DynamicsWorkspace) -> None:
    truth = np.radians([20.0, 71.47, -140.0, 88.53, 20.0, 10.0])
    hand = workspace.hand_pose(State(joints_rad=truth))
    near = solve_ik(
        workspace, hand.pos_robot_m, hand.rot_robot_from_hand, reference_joints_rad=truth
    )
    np.testing.assert_allclose(near[0].joints_rad, truth, atol=1e-8)


def test_ik_round_trips_random_reachable_poses(workspace: DynamicsWorkspace) -> None:
    rng = np.random.default_rng(11)
    for _ in range(5):
        truth = np.radians(rng.uniform(-120.0, 120.0, 6))
        hand = workspace.hand_pose(State(joints_rad=truth))
        best = solve_ik(workspace, hand.pos_robot_m, hand.rot_robot_from_hand)[0]
        reached = workspace.hand_pose(State(joints_rad=best.joints_rad))
        np.testing.assert_allclose(reached.pos_robot_m, hand.pos_robot_m, atol=1e-9)
        err = reached.rot_robot_from_hand @ hand.rot_robot_from_hand.T
        assert rotation_angle_rad(err) < 1e-9


def test_ik_rejects_unreachable_and_malformed_goals(workspace: DynamicsWorkspace) -> None:
    with pytest.raises(InfeasibleGoal, match="beyond the arm's reach"):
        solve_ik(workspace, np.array([5.0, 0.0, 1.0]), np.eye(3))
    with pytest.raises(InvalidInput, match="rotation"):
        solve_ik(workspace, np.array([1.0, 0.0, 1.0]), 2.0 * np.eye(3))
    with pytest.raises(InvalidInput):
        solve_ik(workspace, np.array([np.nan, 0.0, 1.0]), np.eye(3))
    # Within reach but with an orientation the wrist cannot take there.
    with pytest.raises(DidNotConverge):
        solve_ik(
            workspace,
            np.array([0.0, -0.275, 2.5]),
            matrix_from_rpy(np.radians([0, 0, 180])),
            n_starts=4,
        )
