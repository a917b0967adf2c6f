"""A pass schedule: the four experiments in order within one contact window (SPEC 3, 5).

The arm moves between experiments by PTP transfers with wheel feedback on, and waits for the
attitude to settle after each. Every piece is planned on its own (each planner's checks
apply), then the pieces are joined on one 4 Hz grid: attitude-control commands and segments
are shifted to pass time and the whole pass is predicted again, so that the attitude and
the wheel momentum carry over from one experiment to the next.
"""

from __future__ import annotations

import dataclasses
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from planner._builder import CommandBuilder
from planner.attitude_control import AcsGains, AcsMode, default_acs_gains
from planner.coordination import CoordinationParams, plan_coordination
from planner.dynamics import DynamicsWorkspace
from planner.errors import InfeasibleGoal, InvalidInput, PlannerError, name_failure
from planner.experiments import (
    PtpParams,
    ReactionlessParams,
    check_robot,
    plan_ptp,
    plan_reactionless,
)
from planner.gjm import GjmParams, plan_gjm
from planner.gravity_gradient import Orbit, orbit_of_radius
from planner.parameters import parameters_from_values
from planner.plan import AcsCommand, Plan, Segment, check_plan_limits, plan_for_robot
from planner.prediction import predict
from planner.ptp import ptp_commands
from planner.state import VehicleState

if TYPE_CHECKING:
    from planner.robot import RobotDescription

__all__ = ["EXPERIMENTS", "PassParams", "plan_coordination_for", "plan_pass"]

Array = NDArray[np.float64]

EXPERIMENTS = ("ptp", "reactionless", "gjm", "coordination", "nonholonomic")


@dataclass(frozen=True)
class PassParams:
    window_s: float = 1560.0  # SPEC 3/5: about 20 minutes of robot time (26: the flight used three)
    experiments: tuple[str, ...] = EXPERIMENTS
    transfer_settle_s: float = 120.0  # after each PTP transfer: the next starts at rest
    ptp_settle_s: float = 100.0  # experiment 1's settling wait (flight: about 100 s)
    coordination_settle_s: float = 120.0  # each variant starts at rest (paper 3.5)
    coordination_pause_s: float = 0.0  # one back-and-forth motion
    #: Where the pass starts, as parameters (so that the ground re-plans a campaign's pass
    #: from its plan's parameters alone; docs/planning.md): the arm's joints (None: pose
    #: A), the base attitude and rate (orbit frame), the wheels' momentum (base frame).
    start_joints_rad: tuple[float, ...] | None = None
    start_quat_orbit_from_base_xyzw: tuple[float, ...] = (0.0, 0.0, 0.0, 1.0)
    start_omega_base_orbit_radps: tuple[float, ...] = (0.0, 0.0, 0.0)
    start_wheel_momentum_nms: tuple[float, ...] = (0.0, 0.0, 0.0)
    #: The orbit radius of the gravity-gradient torque in the prediction (0: none).
    gravity_gradient_radius_m: float = 0.0

    def check(self) -> None:
        unknown = [e for e in self.experiments if e not in EXPERIMENTS]
        if unknown or not self.experiments:
            raise InvalidInput(f"experiments {list(self.experiments)} must come from {EXPERIMENTS}")
        if not 0 < self.window_s <= 3600:
            raise InvalidInput(f"window_s = {self.window_s} must lie in (0, 3600] s")
        for name, size in (
            ("start_quat_orbit_from_base_xyzw", 4),
            ("start_omega_base_orbit_radps", 3),
            ("start_wheel_momentum_nms", 3),
        ):
            if len(getattr(self, name)) != size:
                raise InvalidInput(f"{name} must hold {size} numbers, got {getattr(self, name)}")
        radius = self.gravity_gradient_radius_m
        if radius != 0.0 and not 6.4e6 <= radius <= 5.0e7:
            raise InvalidInput(
                f"gravity_gradient_radius_m = {radius} must be 0 (none) or lie in [6.4e6, 5e7] m"
            )

    @property
    def has_start(self) -> bool:
        """Whether the parameters name a start other than the nominal one."""
        return (
            self.start_joints_rad is not None
            or tuple(self.start_quat_orbit_from_base_xyzw) != (0.0, 0.0, 0.0, 1.0)
            or any(self.start_omega_base_orbit_radps)
            or any(self.start_wheel_momentum_nms)
        )

    def start_state(self, nominal_joints_rad: Array) -> VehicleState:
        """The start the parameters name (joints ``nominal_joints_rad`` when they name none)."""
        joints = (
            nominal_joints_rad if self.start_joints_rad is None else np.array(self.start_joints_rad)
        )
        return VehicleState(
            joints_rad=joints,
            quat_orbit_from_base_xyzw=np.array(self.start_quat_orbit_from_base_xyzw),
            omega_base_orbit_radps=np.array(self.start_omega_base_orbit_radps),
            wheel_momentum_nms=np.array(self.start_wheel_momentum_nms),
        )

    @classmethod
    def starting_at(cls, state: VehicleState, **others: Any) -> PassParams:
        """Parameters that start the pass at ``state`` (``others``: the rest)."""
        return cls(
            start_joints_rad=tuple(float(v) for v in state.joints_rad),
            start_quat_orbit_from_base_xyzw=tuple(
                float(v) for v in state.quat_orbit_from_base_xyzw
            ),
            start_omega_base_orbit_radps=tuple(float(v) for v in state.omega_base_orbit_radps),
            start_wheel_momentum_nms=tuple(float(v) for v in state.wheel_momentum_nms),
            **others,
        )


def plan_coordination_for(
    ws: DynamicsWorkspace,
    params: CoordinationParams | None = None,
    gains: AcsGains | None = None,
    *,
    robot: RobotDescription | None = None,
) -> Plan:
    """:func:`planner.coordination.plan_coordination` for ``robot`` (``None``: ETS-VII): its
    wheel law, and the plan stamped with it. The experiment flies from the reference pose
    (all zeros unless the description names one), which must be the robot's pose A."""
    check_robot(ws, robot)
    if robot is not None:
        if "A" in robot.poses:
            pose_a = robot.target_joints_rad("A", ws, experiment="coordination")
            reference = ws.model.reference_joints
            if np.any(pose_a != reference):
                raise InvalidInput(
                    f"coordination: flies from the reference pose "
                    f"({np.round(np.degrees(reference), 3).tolist()} deg), and robot "
                    f"{robot.name!r}'s pose A is not it "
                    f"({np.round(np.degrees(pose_a), 3).tolist()} deg): name A as the "
                    "description's reference_pose"
                )
        gains = gains or robot.acs_gains(ws)
    return plan_for_robot(plan_coordination(ws, params or CoordinationParams(), gains), robot)


def _robot_params(
    robot: RobotDescription | None, experiment: str, params_type: type[Any], **overrides: Any
) -> Any:
    """The experiment's parameters: the robot's defaults (its ``[experiments.NAME]`` table)
    under ``overrides``; ETS-VII's built-in defaults without a robot."""
    if robot is None:
        return params_type(**overrides)
    return parameters_from_values(
        params_type, overrides, defaults=robot.experiment_defaults(experiment)
    )


def _experiment_plans(
    ws: DynamicsWorkspace,
    params: PassParams,
    gains: AcsGains,
    robot: RobotDescription | None = None,
) -> list[Plan]:
    plans = []
    for name in params.experiments:
        try:
            plans.append(_experiment_plan(ws, params, gains, robot, name))
        except PlannerError as exc:
            names = [f.name for f in dataclasses.fields(_params_type(name))]
            message = str(name_failure(exc, name, names))
            exc.args = (
                f"pass: the {name} experiment failed (its parameters: the description's "
                f"[experiments.{name}] table; or drop it from experiments): {message}",
            )
            raise
    return plans


def _params_type(name: str) -> type[Any]:
    if name == "nonholonomic":
        from planner.nonholonomic import NonholonomicParams

        return NonholonomicParams
    types: dict[str, type[Any]] = {
        "ptp": PtpParams,
        "reactionless": ReactionlessParams,
        "gjm": GjmParams,
        "coordination": CoordinationParams,
    }
    return types[name]


def _experiment_plan(
    ws: DynamicsWorkspace,
    params: PassParams,
    gains: AcsGains,
    robot: RobotDescription | None,
    name: str,
) -> Plan:
    """One experiment of the pass, with the robot's defaults and the pass's waits."""
    if name == "ptp":
        ptp = _robot_params(robot, name, PtpParams, settle_s=params.ptp_settle_s)
        return plan_ptp(ws, ptp, gains, robot=robot)
    if name == "reactionless":
        reactionless = _robot_params(robot, name, ReactionlessParams)
        return plan_reactionless(ws, reactionless, gains, robot=robot)
    if name == "gjm":
        return plan_gjm(ws, _robot_params(robot, name, GjmParams), robot=robot)
    if name == "coordination":
        coordination = _robot_params(
            robot,
            name,
            CoordinationParams,
            settle_s=params.coordination_settle_s,
            pause_s=params.coordination_pause_s,
        )
        return plan_coordination_for(ws, coordination, gains, robot=robot)
    from planner.nonholonomic import NonholonomicParams, plan_nonholonomic

    nonholonomic = _robot_params(robot, name, NonholonomicParams)
    return plan_nonholonomic(ws, nonholonomic, robot=robot)


def plan_pass(
    ws: DynamicsWorkspace,
    params: PassParams = PassParams(),
    gains: AcsGains | None = None,
    *,
    robot: RobotDescription | None = None,
    initial_state: VehicleState | None = None,
    orbit: Orbit | None = None,
) -> Plan:
    """The experiments of ``params`` in order, from pose A, as one plan: ``robot``'s
    experiments with its poses and default parameters (``None``: ETS-VII's built-in ones).

    ``initial_state`` starts the pass where another left the vehicle (a campaign's previous
    pass and the gap after it): the arm at rest at its joints (a PTP transfer takes it to the
    first experiment's start), the base at its attitude and rate, the wheels holding its
    momentum; the whole pass is predicted from there (the flight rules then see the carried
    momentum). ``None``: pose A, the orbit frame's attitude at rest, wheels empty.
    ``orbit`` adds the gravity-gradient torque on that orbit to the prediction (eq. 11; the
    default, ``None``, leaves it out as every planner's prediction does). Both may be given
    as ``params`` instead (``start_*``, ``gravity_gradient_radius_m``), which the plan's
    parameters then record; not both ways at once."""
    params.check()
    check_robot(ws, robot)
    model = ws.model
    if robot is None:
        gains = gains or default_acs_gains(ws)
        start = np.zeros(model.n_joints)
    else:
        gains = gains or robot.acs_gains(ws)
        start = robot.target_joints_rad("A", ws, experiment="pass")
    if params.has_start:
        if initial_state is not None:
            raise InvalidInput("the pass's start is given twice: as parameters and a state")
        initial_state = params.start_state(start)
    if params.gravity_gradient_radius_m > 0.0:
        if orbit is not None:
            raise InvalidInput("the pass's orbit is given twice: as a parameter and an orbit")
        orbit = orbit_of_radius(params.gravity_gradient_radius_m)
    if initial_state is not None:
        if initial_state.joints_rad.shape != (model.n_joints,):
            raise InvalidInput(
                f"initial_state has {initial_state.joints_rad.size} joints, the robot "
                f"{model.n_joints}"
            )
        model.check_joints(initial_state.joints_rad)
        start = initial_state.joints_rad.copy()
    pieces = _experiment_plans(ws, params, gains, robot)
    builder = CommandBuilder(start)
    acs: list[AcsCommand] = [AcsCommand(0.0, AcsMode.FEEDBACK)]
    segments: list[Segment] = []
    metrics: dict[str, float] = {}

    def nominal_feedback() -> None:
        # Between experiments the wheels hold the nominal attitude (transfers included).
        last = acs[-1]
        if (
            last.mode is not AcsMode.FEEDBACK
            or last.feedforward
            or not np.allclose(last.target_quat_orbit_from_base_xyzw, [0.0, 0.0, 0.0, 1.0])
        ):
            acs.append(AcsCommand(builder.t_s, AcsMode.FEEDBACK))

    for piece in pieces:
        nominal_feedback()
        if not np.allclose(builder.joints_rad, piece.initial_joints_rad, atol=1e-9):
            _, move = ptp_commands(model, builder.joints_rad, piece.initial_joints_rad)
            builder.block(move, f"transfer to {piece.experiment}", "ptp")
            builder.hold(params.transfer_settle_s, f"settle before {piece.experiment}", "settle")
        offset = builder.t_s
        builder.block(piece.command_joints_rad, piece.experiment, piece.segments[0].kind)
        builder.segments.pop()  # replaced by the piece's own segments below
        segments.extend(builder.segments)
        builder.segments.clear()
        segments.extend(
            Segment(
                f"{piece.experiment}: {s.name}", s.kind, s.t_start_s + offset, s.t_end_s + offset
            )
            for s in piece.segments
        )
        acs.extend(
            AcsCommand(c.t_s + offset, c.mode, c.target_quat_orbit_from_base_xyzw, c.feedforward)
            for c in piece.acs_commands
        )
        for key, value in piece.metrics.items():
            metrics[f"{piece.experiment}.{key}"] = value
        metrics[f"{piece.experiment}.start_s"] = offset
    nominal_feedback()
    segments.extend(builder.segments)
    times, joints = builder.arrays()
    if times[-1] > params.window_s:
        raise InfeasibleGoal(
            f"pass: the pass needs {times[-1]:.1f} s (it ends at t = {times[-1]:.1f} s), more "
            f"than the {params.window_s:.1f} s window (window_s): drop an experiment from "
            "experiments or shorten the settling waits"
        )
    prediction = predict(
        ws,
        times,
        joints,
        acs_commands=acs,
        acs_gains=gains,
        initial_quat_orbit_from_base_xyzw=(
            None if initial_state is None else initial_state.quat_orbit_from_base_xyzw
        ),
        initial_wheel_momentum_nms=(
            None if initial_state is None else initial_state.wheel_momentum_nms
        ),
        initial_omega_base_orbit_radps=(
            None if initial_state is None else initial_state.omega_base_orbit_radps
        ),
        orbit=orbit,
    )
    metrics["duration_s"] = float(times[-1])
    metrics["window_margin_s"] = float(params.window_s - times[-1])
    if orbit is not None:
        metrics["gravity_gradient_orbit_radius_m"] = orbit.radius_m
    plan = Plan(
        experiment="pass",
        parameters={**asdict(params), "experiments": list(params.experiments)},
        initial_joints_rad=start,
        command_times_s=times,
        command_joints_rad=joints,
        segments=tuple(segments),
        prediction=prediction,
        metrics=metrics,
        acs_commands=tuple(sorted(acs, key=lambda c: c.t_s)),
        initial_quat_orbit_from_base_xyzw=(
            np.array([0.0, 0.0, 0.0, 1.0])
            if initial_state is None
            else initial_state.quat_orbit_from_base_xyzw.copy()
        ),
    )
    check_plan_limits(model, plan)
    return plan_for_robot(plan, robot)
