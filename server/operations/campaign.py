"""A campaign: the experiments flown over consecutive contact windows, one plan per pass,
each pass starting where the one before left the vehicle (docs/missions.md, Campaigns;
SPEC sections 3, 5 and 8).

    plan_campaign(mission, start_utc, robot=None, assignment=None, on_progress=None)
        -> Campaign
    Campaign.passes[i]: .index .window .experiments .plan .start_state .end_state
        .gap_momentum_nms (and .gap_gravity_gradient_nms, .gap_s, .flight_rules)
    Campaign.to_dict() -> campaign.json (hikoboshi plan campaign writes it with each plan)
    load_campaign(path) -> mission.campaign.CampaignRecord

Why it lives here: planning needs the planner and the windows need the mission, and the
``mission`` package imports nothing else of ours (an import contract in pyproject.toml);
operations may import both, and the command line, the ground and the campaign demo use it
alike. What needs only the orbit (the windows' chaining, ``|r|^-3`` over a gap, the file read
back) is in ``mission/campaign.py``; the gap's arithmetic is :mod:`server.operations.
campaign_gap`'s. Each pass is planned and checked by the one checked planning call
(:func:`server.operations.planning.plan_checked`).

The rules it keeps:

- Pass k takes the first window whose net time (after the mission's AOS margin) starts at
  or after the previous pass's last command; its plan starts ``start_lead_s`` after the net
  start (the ground's start lead, 31.25 s with its default settings), and the plan
  with that lead must fit the net time (else :class:`CampaignInfeasible`, naming the pass).
- The default assignment is the paper's four experiments in its order (SPEC 3: 1
  reactionless with its PTP baseline, 2 GJM, 3 attitude coordination, 4 non-holonomic)
  over its three passes (SPEC 8, paper 3.1): ``DEFAULT_ASSIGNMENT``. The paper does not
  say which pass flew which; the split at the experiments' boundaries is our choice.
- Each pass's prediction includes the gravity-gradient torque (eq. 11) on the planner's
  circular orbit at the vehicle's mean SGP4 radius over the pass, so its end state carries
  what the pass itself loaded.
- Between passes the arm rests where the pass left it and attitude control holds the base at
  the pass's last attitude target: the base's own residual momentum settles into the wheels
  (angular momentum is conserved), and the gravity-gradient torque over the gap, from the
  mission's SGP4 orbit, loads them (:func:`server.operations.campaign_gap.gap_transition`).
  So pass k+1 starts at pass k's joints, the held attitude, at rest, with pass k's wheel
  momentum plus ``gap_momentum_nms``.
- Each plan is checked against the robot's flight rules (``fits_pass`` against the net
  time less the lead); the report travels in the plan file, as ``hikoboshi plan`` writes it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from mission.campaign import (
    CAMPAIGN_FORMAT_VERSION,
    GAP_STEP_S,
    load_campaign,
    next_window,
    orbit_radius_m,
)
from mission.errors import MissionError
from mission.file import Mission
from mission.windows import Window, compute_windows, format_utc
from server.operations.campaign_gap import GRAVITY_MU_M3PS2, gap_transition
from server.operations.windows import PassWindow, check_fit
from server.operations.windows import start_lead_s as ground_start_lead_s
from server.services.errors import DomainError
from server.settings import Settings

if TYPE_CHECKING:
    from planner.flight_rules import FlightRulesReport
    from planner.plan import Plan
    from planner.robot import RobotDescription
    from planner.state import VehicleState

__all__ = [
    "DEFAULT_ASSIGNMENT",
    "DEFAULT_START_LEAD_S",
    "SEARCH_HOURS",
    "Campaign",
    "CampaignInfeasible",
    "CampaignPass",
    "load_campaign",
    "parse_assignment",
    "plan_campaign",
]

Array = NDArray[np.float64]

#: SPEC 3 in the paper's order over its three passes (our split, docs/missions.md).
DEFAULT_ASSIGNMENT: tuple[tuple[str, ...], ...] = (
    ("ptp", "reactionless", "gjm"),
    ("coordination",),
    ("nonholonomic",),
)
#: The ground's start lead at time scale 1 with its default settings
#: (:func:`server.operations.windows.start_lead_s`): a pass's plan starts this long after
#: the window's net start at most.
DEFAULT_START_LEAD_S = ground_start_lead_s(Settings())
#: How far from the start the windows are searched (a LEO-GEO window comes every orbit).
SEARCH_HOURS = 24.0
#: At most this many passes in one campaign.
MAX_PASSES = 16

#: ``on_progress(done, total, what)``: steps done of the total, and what is being done.
ProgressFn = Callable[[int, int, str], None]


class CampaignInfeasible(MissionError, ValueError):
    """A campaign that cannot be planned: the message names the pass and the quantity."""


@dataclass(frozen=True, eq=False)
class CampaignPass:
    """One pass: its window, its experiments, its plan, and the vehicle at its ends."""

    index: int  # 1, 2, ...
    window: Window
    experiments: tuple[str, ...]
    plan: Plan
    plan_start_utc: datetime  # the plan's t = 0: the window's net start + the start lead
    start_state: VehicleState
    end_state: VehicleState
    #: from the previous pass's last command to this pass's first (0 for the first pass)
    gap_s: float
    #: start_state's wheel momentum less the previous pass's end_state's (base frame)
    gap_momentum_nms: Array
    #: the gravity-gradient share of it (the rest is the base's residual rate settled)
    gap_gravity_gradient_nms: Array
    flight_rules: FlightRulesReport | None

    @property
    def plan_end_utc(self) -> datetime:
        return self.plan_start_utc + timedelta(seconds=self.plan.duration_s)

    @property
    def plan_file(self) -> str:
        return f"pass-{self.index}.plan.json"

    def to_dict(self) -> dict[str, Any]:
        window = self.window
        return {
            "index": self.index,
            "window": {
                **window.to_dict(),
                "aos_margin_s": window.aos_margin_s,
                "los_margin_s": window.los_margin_s,
            },
            "experiments": list(self.experiments),
            "plan_file": self.plan_file,
            "plan_start_utc": format_utc(self.plan_start_utc),
            "plan_end_utc": format_utc(self.plan_end_utc),
            "duration_s": self.plan.duration_s,
            "spare_s": (window.net_end_utc - self.plan_end_utc).total_seconds(),
            "start_state": self.start_state.to_dict(),
            "end_state": self.end_state.to_dict(),
            "gap_s": self.gap_s,
            "gap_momentum_nms": [float(v) for v in self.gap_momentum_nms],
            "gap_gravity_gradient_nms": [float(v) for v in self.gap_gravity_gradient_nms],
            "flight_rules_passed": None if self.flight_rules is None else self.flight_rules.passed,
        }


@dataclass(frozen=True, eq=False)
class Campaign:
    """The passes of a campaign, in order (``plan_campaign``)."""

    mission: Mission
    start_utc: datetime
    robot: str
    robot_hash: str
    start_lead_s: float
    passes: tuple[CampaignPass, ...]

    @property
    def passed(self) -> bool:
        """Every plan checked and clear of the flight rules."""
        return all(p.flight_rules is not None and p.flight_rules.passed for p in self.passes)

    def to_dict(self) -> dict[str, Any]:
        return {
            "format_version": CAMPAIGN_FORMAT_VERSION,
            "mission": self.mission.name,
            "mission_sha256": self.mission.content_sha256,
            "vehicle": self.mission.vehicle,
            "start_utc": format_utc(self.start_utc),
            "robot": self.robot,
            "robot_hash": self.robot_hash,
            "start_lead_s": self.start_lead_s,
            "gravity_gradient": {"mu_m3ps2": GRAVITY_MU_M3PS2, "max_step_s": GAP_STEP_S},
            "assignment": [list(p.experiments) for p in self.passes],
            "passes": [p.to_dict() for p in self.passes],
        }


def parse_assignment(text: str) -> tuple[tuple[str, ...], ...]:
    """``"ptp,reactionless/gjm/coordination"``: passes split by ``/``, experiments by ``,``."""
    return tuple(tuple(e.strip() for e in part.split(",") if e.strip()) for part in text.split("/"))


def _check_assignment(assignment: Sequence[Sequence[str]]) -> tuple[tuple[str, ...], ...]:
    from planner.schedule import EXPERIMENTS

    if isinstance(assignment, str):
        raise CampaignInfeasible("the assignment is a sequence of passes, not a string")
    passes = tuple(tuple(str(e) for e in experiments) for experiments in assignment)
    if not passes:
        raise CampaignInfeasible("the assignment has no pass")
    if len(passes) > MAX_PASSES:
        raise CampaignInfeasible(f"the assignment has {len(passes)} passes, over {MAX_PASSES}")
    for k, experiments in enumerate(passes, start=1):
        if not experiments:
            raise CampaignInfeasible(f"pass {k}: no experiment assigned")
        for name in experiments:
            if name not in EXPERIMENTS:
                raise CampaignInfeasible(
                    f"pass {k}: unknown experiment {name!r} (known: {', '.join(EXPERIMENTS)})"
                )
    return passes


def _pass_radius_m(mission: Mission, start_utc: datetime, end_utc: datetime) -> float:
    """The vehicle's mean SGP4 radius over a pass's usable time: the circular orbit of the
    pass's own gravity-gradient torque (eq. 11, the orbit frame inertial over a pass, SPEC
    2); the radius varies by parts in a thousand over a pass."""
    span_s = (end_utc - start_utc).total_seconds()
    samples = [start_utc + timedelta(seconds=s) for s in np.linspace(0.0, span_s, 61)]
    return float(np.mean(orbit_radius_m(mission, samples)))


def _held_attitude(plan: Plan, index: int) -> Array:
    """The attitude target attitude control holds after ``plan`` (its last ACS command)."""
    from planner.attitude_control import AcsMode

    if not plan.acs_commands or plan.acs_commands[-1].mode is not AcsMode.FEEDBACK:
        raise CampaignInfeasible(
            f"pass {index}: the plan does not end with attitude control on (feedback), so "
            "nothing holds the attitude in the gap"
        )
    return np.asarray(plan.acs_commands[-1].target_quat_orbit_from_base_xyzw, dtype=float)


def plan_campaign(
    mission: Mission,
    start_utc: datetime,
    robot: RobotDescription | None = None,
    assignment: Sequence[Sequence[str]] | None = None,
    on_progress: ProgressFn | None = None,
    *,
    start_lead_s: float = DEFAULT_START_LEAD_S,
    check_rules: bool = True,
) -> Campaign:
    """The experiments of ``assignment`` (default :data:`DEFAULT_ASSIGNMENT`), one pass per
    entry, over the consecutive windows from ``start_utc`` (see the module docstring);
    ``robot``: its description (``None``: ETS-VII). :class:`CampaignInfeasible` names the
    pass and the quantity when a pass has no window within ``SEARCH_HOURS``, a plan does not
    fit its window or an experiment is unknown; a planner's own refusal is re-raised as one,
    naming the pass."""
    from planner.catalogue import plan_experiment
    from planner.dynamics import DynamicsWorkspace
    from planner.errors import PlannerError
    from planner.model import default_model
    from planner.schedule import PassParams
    from planner.state import VehicleState
    from server.operations.planning import plan_checked

    passes_wanted = _check_assignment(DEFAULT_ASSIGNMENT if assignment is None else assignment)
    if not 0.0 <= start_lead_s <= 600.0:
        raise CampaignInfeasible(f"start lead {start_lead_s:g} s is outside [0, 600] s")
    start_utc = start_utc.astimezone(UTC)
    total = 1 + len(passes_wanted)
    done = 0

    def step(what: str) -> None:
        nonlocal done
        if on_progress is not None:
            on_progress(done, total, what)
        done += 1

    step("computing the windows")
    windows = compute_windows(mission, start_utc, SEARCH_HOURS)
    ws = DynamicsWorkspace(robot.model if robot is not None else default_model())
    passes: list[CampaignPass] = []
    not_before = start_utc
    state: VehicleState | None = None
    previous: CampaignPass | None = None
    for k, experiments in enumerate(passes_wanted, start=1):
        window = next_window(windows, not_before)
        if window is None:
            raise CampaignInfeasible(
                f"pass {k}: no window's net time starts between {format_utc(not_before)} and "
                f"{format_utc(start_utc + timedelta(hours=SEARCH_HOURS))} (the "
                f"{SEARCH_HOURS:g} h searched from the start)"
            )
        plan_start = window.net_start_utc + timedelta(seconds=start_lead_s)
        where = f"pass {k} ({window.relay}, AOS {format_utc(window.aos_utc)})"
        usable_s = window.net_s - start_lead_s
        if usable_s <= 0.0:
            raise CampaignInfeasible(
                f"{where}: the window's net time {window.net_s:.1f} s does not hold the "
                f"{start_lead_s:g} s start lead"
            )
        gap_s = 0.0
        gap_momentum = np.zeros(3)
        gap_loaded = np.zeros(3)
        if previous is not None:
            assert state is not None
            gap_s = (plan_start - previous.plan_end_utc).total_seconds()
            start_state, gap_loaded = gap_transition(
                ws,
                mission,
                state,
                _held_attitude(previous.plan, previous.index),
                previous.plan_end_utc,
                plan_start,
            )
            gap_momentum = start_state.wheel_momentum_nms - state.wheel_momentum_nms
        else:
            start_state = None
        step(f"planning and checking pass {k}: {', '.join(experiments)}")
        # The start and the orbit go in as parameters, so that the plan records them and the
        # ground re-plans the same pass from them (POST /api/plans, experiment "pass").
        others: dict[str, Any] = {
            "window_s": min(usable_s, 3600.0),
            "experiments": experiments,
            "gravity_gradient_radius_m": _pass_radius_m(mission, plan_start, window.net_end_utc),
        }
        pass_window = PassWindow.of_mission(window, mission.name)
        try:
            params = (
                PassParams(**others)
                if start_state is None
                else PassParams.starting_at(start_state, **others)
            )
            if check_rules:  # the flight rules and the window-fit rule, in the one call
                checked = plan_checked(
                    "pass", params, robot=robot, window=pass_window, lead_s=start_lead_s
                )
                plan, report, misfit = checked.plan, checked.report, checked.misfit
            else:  # the windows and states alone (the tests of those)
                plan, report = plan_experiment("pass", params, robot=robot), None
                misfit = check_fit(
                    pass_window,
                    plan_id=f"of pass {k}",
                    plan_s=plan.duration_s,
                    lead_s=start_lead_s,
                )
        except DomainError as exc:
            raise CampaignInfeasible(f"{where}: {exc.message}") from exc
        except PlannerError as exc:
            if "window" in str(exc):
                raise CampaignInfeasible(
                    f"{where}: the plan does not fit the window's net time less the "
                    f"{start_lead_s:g} s start lead ({usable_s:.1f} s): {exc}"
                ) from exc
            raise CampaignInfeasible(f"{where}: {exc}") from exc
        if misfit is not None:
            raise CampaignInfeasible(f"{where}: {misfit.message}")
        end_state = VehicleState.at_end_of(plan.prediction)
        current = CampaignPass(
            index=k,
            window=window,
            experiments=experiments,
            plan=plan,
            plan_start_utc=plan_start,
            start_state=start_state or VehicleState(joints_rad=plan.initial_joints_rad),
            end_state=end_state,
            gap_s=gap_s,
            gap_momentum_nms=gap_momentum,
            gap_gravity_gradient_nms=gap_loaded,
            flight_rules=report,
        )
        passes.append(current)
        previous, state = current, end_state
        not_before = current.plan_end_utc
    if on_progress is not None:
        on_progress(total, total, "done")
    return Campaign(
        mission=mission,
        start_utc=start_utc,
        robot=passes[0].plan.robot,
        robot_hash=passes[0].plan.robot_hash,
        start_lead_s=start_lead_s,
        passes=tuple(passes),
    )
