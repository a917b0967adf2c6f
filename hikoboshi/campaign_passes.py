"""What the campaign demo flies (:mod:`hikoboshi.campaign_demo`): its options, and its
passes: which experiments go in which window (the campaign planner's,
:func:`server.operations.campaign.plan_campaign`, whose plan documents the demo uploads,
or given experiments over the first windows that hold them) and the relay service each
pass books in its window.

The relay is booked per pass, as TDRS time was (shared among NASA's users): the link is up
from the window's AOS to the end of its pass and :data:`SERVICE_TAIL_S`, never past the
window's LOS nor the next pass's AOS (one relay at a time); the rest is flown fast.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

from hikoboshi.demo_harness import DemoError
from server.operations.windows import PassWindow, check_fit

__all__ = [
    "PAPER_ORDER",
    "SERVICE_TAIL_S",
    "START_ALLOWANCE_S",
    "START_ALLOWANCE_WALL_S",
    "CampaignOptions",
    "default_start",
]

#: With a relay given and no experiments: the experiments of each pass, the paper's order
#: over three.
PAPER_ORDER: tuple[tuple[str, ...], ...] = (
    ("ptp", "reactionless"),
    ("gjm", "coordination"),
    ("nonholonomic",),
)
#: What a pass keeps for its start (the ground's start lead and the request's slack):
#: this many onboard s, and START_ALLOWANCE_WALL_S of wall time (the job's polling and the
#: start request on a loaded machine) at the demo's speed.
START_ALLOWANCE_S = 60.0
START_ALLOWANCE_WALL_S = 5.0
#: Onboard s the relay service runs on after a pass's plan ends: the last echoes and the
#: telemetry still in the onboard store come down, through the loss's resends.
SERVICE_TAIL_S = 300.0


@dataclass(frozen=True)
class CampaignOptions:
    mission: Path
    start_utc: datetime
    out: Path = Path("out/campaign")
    speed: float = 20.0
    loss: float = 0.0
    port: int = 8000
    seed: int = 0
    #: the gaps at most this many times wall time (None: as fast as the vehicle computes)
    fast_scale: float | None = None
    #: wall s for each pass (from its start request to its end)
    timeout_s: float = 900.0
    log_format: str = "text"
    log_level: str = "info"
    #: the experiments of each pass, over the first windows that hold them, in place of the
    #: campaign's (a shorter campaign: the tests)
    pass_experiments: tuple[tuple[str, ...], ...] | None = None
    #: with ``pass_experiments`` or without mission.campaign: only this relay's windows
    relay: str | None = None
    #: where the passes are not the campaign planner's: more of their plan parameters
    #: (``planner.schedule.PassParams``, e.g. a shorter ``ptp_settle_s``: the tests)
    pass_parameters: dict[str, Any] | None = None
    #: onboard s each pass keeps its relay after its plan ends (a shorter booking: the tests)
    service_tail_s: float = SERVICE_TAIL_S
    #: the campaign planner's passes, each its experiments (None: the paper's
    #: ``DEFAULT_ASSIGNMENT``; a shorter campaign of uploaded plans: the tests)
    assignment: tuple[tuple[str, ...], ...] | None = None


@dataclass(frozen=True)
class _PassSpec:
    window: Any  # mission.Window
    experiments: tuple[str, ...]
    #: the wheel momentum predicted to be loaded between the previous pass and this one
    gap_momentum_nms: list[float] | None
    #: the plan's parameters (the campaign's: its start state and orbit), else None: the
    #: ground plans ``experiments`` from the nominal start
    parameters: dict[str, Any] | None = None
    #: the campaign's plan, as a document (None: the ground plans ``parameters``)
    document: str | None = None
    #: the campaign's predicted wheel momentum at the plan's start and end (N m s)
    predicted_start_h: list[float] | None = None
    predicted_end_h: list[float] | None = None


def _campaign(options: CampaignOptions, plan_duration: Any) -> list[_PassSpec]:
    """The passes: the campaign planner's (:func:`server.operations.campaign.plan_campaign`,
    each with its plan document), or,
    with ``pass_experiments`` or ``relay``, those experiments over the first windows (from
    the start, 24 h; the relay's only) whose net time holds each pass's plan."""
    from mission import compute_windows, load_mission
    from server.operations.campaign import plan_campaign

    mission = load_mission(options.mission)
    if options.pass_experiments is None and options.relay is None:
        campaign = plan_campaign(mission, options.start_utc, assignment=options.assignment)

        def floats(values: Any) -> list[float]:
            return [float(x) for x in values]

        return [
            _PassSpec(
                window=p.window,
                experiments=tuple(p.experiments),
                gap_momentum_nms=floats(p.gap_momentum_nms) if p.index > 1 else None,
                parameters=dict(p.plan.parameters),
                document=p.plan.to_json(),
                predicted_start_h=floats(p.start_state.wheel_momentum_nms),
                predicted_end_h=floats(p.end_state.wheel_momentum_nms),
            )
            for p in campaign.passes
        ]
    windows = compute_windows(mission, options.start_utc, 24.0)
    if options.relay is not None:
        windows = [w for w in windows if w.relay == options.relay]
    specs: list[_PassSpec] = []
    after = options.start_utc
    for experiments in options.pass_experiments or PAPER_ORDER:
        need_s = plan_duration(experiments) + _allowance_s(options.speed)
        window = next((w for w in windows if w.net_start_utc >= after and w.net_s >= need_s), None)
        if window is None:
            raise DemoError(f"no window in 24 h holds a pass of {', '.join(experiments)}")
        specs.append(_PassSpec(window, experiments, None))
        after = window.net_start_utc + timedelta(seconds=need_s)
    return specs


def _allowance_s(speed: float) -> float:
    return START_ALLOWANCE_S + START_ALLOWANCE_WALL_S * speed


def _service_windows(
    specs: list[_PassSpec],
    durations_s: list[float],
    speed: float,
    tail_s: float = SERVICE_TAIL_S,
) -> list[Any]:
    """The relay service each pass books in its window: from the window's AOS to the end
    of the pass (its net start, the start allowance and the plan) and ``tail_s``
    (:data:`SERVICE_TAIL_S`), never past the window's LOS nor the next window's AOS (one
    relay at a time). Raises DemoError when a pass does not fit its window's net time."""

    services = []
    for i, (spec, duration_s) in enumerate(zip(specs, durations_s, strict=True)):
        w = spec.window
        allowance_s = _allowance_s(speed)
        misfit = check_fit(
            PassWindow.of_mission(w),
            plan_id=f"of pass {i + 1}",
            plan_s=duration_s,
            lead_s=allowance_s,
            available_s=w.net_s,
        )
        if misfit is not None:
            raise DemoError(misfit.message)
        end = w.net_start_utc + timedelta(seconds=allowance_s + duration_s + tail_s)
        end = min(end, w.los_utc)
        if i + 1 < len(specs):
            end = min(end, specs[i + 1].window.aos_utc)
        if end < w.net_start_utc + timedelta(seconds=allowance_s + duration_s):
            raise DemoError(f"pass {i + 1} overlaps the next pass's window")
        services.append(replace(w, los_utc=end, los_margin_s=0.0))
    return services


def default_start() -> datetime:
    """The campaign's default start: 1999-09-30T00:00:00Z (the paper's campaign day)."""
    return datetime(1999, 9, 30, tzinfo=UTC)
