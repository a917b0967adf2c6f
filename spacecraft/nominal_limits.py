"""The nominal maxima the live limits keep clear of: a robot's whole pass flown offline.

SPEC 8 asks that the live limits (planner.limits) be "set from the nominal pass's measured
maxima with margin, so that a nominal pass never raises one". This flies a robot's nominal
pass (every experiment of its schedule, ``planner.schedule.plan_pass``, as the demo plans
it) through the simulated vehicle (:class:`~spacecraft.vehicle.Vehicle`: its servos,
attitude control, wheels, sensor noise) for several sensor-noise seeds, with the commands
uplinked as the ground does (each once its tag is within the uplink's lead window of the
onboard clock, arriving one relay delay later: what the schedule's occupancy sees), and
evaluates every frame with :class:`telemetry.limits.FrameEvaluator`: the tracking error
against the plan's commands interpolated at the frame's time, as the ground computes it, and
the clearance exact at every frame. Per quantity it gives the worst nominal value (the
largest; the smallest for a "low" quantity) and where each band stands against it.

The link quantities (``frames_behind``, ``frame_age_s``) are the ground's, not a frame's:
their nominal worst is computed from the relay (:func:`link_nominal`: the demo's 30 s
outage with the 3 s one-way delay each way), not flown.

``hikoboshi model limits [--robot FILE] [--fly]`` prints the table (docs/robots.md,
"Limits", holds the numbers it measured for ETS-VII and Orihime).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from planner.catalogue import parse_assignments, plan_experiment, resolve
from planner.limits import QUANTITIES, Limits, channel_names
from planner.plan import Plan
from planner.robot import RobotDescription
from spacecraft.vehicle import Vehicle
from spacecraft.vehicle_config import vehicle_config_for
from telemetry.limits import FRAME_QUANTITIES, for_description, interpolated_commands
from telemetry.uplink import plan_commands
from telemetry.wire import CommandStage, JointCommandMsg, TelemetryFrame

__all__ = [
    "DEFAULT_SEEDS",
    "LinkNominal",
    "NominalFlight",
    "QuantityRow",
    "fly_nominal",
    "format_table",
    "limits_table",
    "link_nominal",
    "nominal_plan",
]

Array = NDArray[np.float64]

#: Sensor-noise seeds flown by default (the issue's "seeds 1 to 5").
DEFAULT_SEEDS = (1, 2, 3, 4, 5)
#: The ground's uplink: a command goes up once its tag is within this of the onboard clock
#: (server.settings.Settings.uplink_lead_window_s's default) ...
LEAD_WINDOW_S = 120.0
#: ... and reaches the vehicle one relay delay later (spacecraft.link's default, one way).
RELAY_DELAY_S = 3.0
#: The plan's t = 0 is this long after the vehicle starts (whole seconds).
START_S = 5.0
#: Flown past the last command: the settling the evaluator should see too.
AFTER_S = 5.0
#: Frames per evaluation batch (as the ground ingests them, a message at a time).
BATCH = 50


@dataclass(frozen=True)
class LinkNominal:
    """The relay the nominal link quantities are computed for (the demo's)."""

    outage_s: float = 30.0
    delay_s: float = RELAY_DELAY_S
    telemetry_rate_hz: float = 10.0
    #: frames go down as they are made: at most one telemetry period late, s
    batch_s: float = 0.1

    @property
    def frame_age_s(self) -> float:
        """The newest frame's age on the ground at the end of the outage: the outage, the
        delay each way (its last frames were in flight, the first after it are too), and
        one batch."""
        return self.outage_s + 2.0 * self.delay_s + self.batch_s

    @property
    def frames_behind(self) -> float:
        """Frames generated onboard that the ground does not hold then."""
        return math.ceil(self.frame_age_s * self.telemetry_rate_hz)


def link_nominal(link: LinkNominal | None = None) -> dict[str, float]:
    """The link quantities' nominal worst (the demo's outage: computed, not flown)."""
    link = link or LinkNominal()
    return {"frames_behind": link.frames_behind, "frame_age_s": link.frame_age_s}


@dataclass(frozen=True)
class NominalFlight:
    """One seed's flight: every frame's values (``quantity -> (m, channels)``), the
    commands the vehicle refused (0 for a nominal pass) and the plan's duration."""

    seed: int
    values: dict[str, Array]
    rejected: int
    frames: int
    duration_s: float

    def worst(self, quantity: str) -> tuple[float, int]:
        """The worst value over the frames and channels (largest for "high", smallest for
        "low"; NaN ignored) and its channel's index."""
        v = self.values[quantity]
        if v.size == 0 or np.all(np.isnan(v)):
            return math.nan, -1
        if QUANTITIES[quantity].direction == "high":
            flat = int(np.nanargmax(v))
        else:
            flat = int(np.nanargmin(v))
        return float(v.flat[flat]), flat % v.shape[1]


def nominal_plan(
    description: RobotDescription, experiment: str = "pass", experiments: Sequence[str] = ()
) -> Plan:
    """The robot's nominal ``experiment`` with its description's defaults, as the demo plans
    it (the whole pass by default; ``experiments``: a subset of the pass's schedule)."""
    params_type, _ = resolve(experiment)
    params = parse_assignments(
        params_type, [], defaults=description.experiment_defaults(experiment)
    )
    if experiment == "pass" and experiments:
        params = replace(params, experiments=tuple(experiments))
    return plan_experiment(experiment, params, robot=description)


def fly_nominal(
    description: RobotDescription,
    plan: Plan,
    *,
    seed: int,
    lead_window_s: float = LEAD_WINDOW_S,
    delay_s: float = RELAY_DELAY_S,
    exact_clearance: bool = True,
    limits: Limits | None = None,
    progress: Callable[[float], None] | None = None,
) -> NominalFlight:
    """Fly ``plan`` through the robot's vehicle (sensor-noise ``seed``), its commands
    arriving as the ground uplinks them, and evaluate every frame (module docstring)."""
    epoch_ns = 0
    t0_ns = round(START_S * 1e9)
    commands = plan_commands(plan, epoch_ns=t0_ns, first_seq=0)
    joints = [c for c in commands if isinstance(c, JointCommandMsg)]
    tags = np.array([c.execute_time_ns for c in joints], dtype=np.int64)
    commanded = interpolated_commands(tags, np.array([c.joints_rad for c in joints]))
    config = vehicle_config_for(
        description, initial_joints_rad=tuple(float(v) for v in plan.initial_joints_rad)
    )
    vehicle = Vehicle(config, epoch_ns=epoch_ns, seed=seed)
    limits = limits or description.limits
    evaluator = for_description(
        description,
        commanded=commanded,
        limits=limits,
        clearance_threshold_m=math.inf if exact_clearance else None,
    )
    end_ns = max(c.execute_time_ns for c in commands) + round(AFTER_S * 1e9)
    lead_ns = round((lead_window_s - delay_s) * 1e9)
    step_ns = 250_000_000
    pending = 0
    rejected = 0
    frames: list[TelemetryFrame] = []
    chunks: dict[str, list[Array]] = {q: [] for q in FRAME_QUANTITIES}
    t = epoch_ns
    while t < end_ns:
        while pending < len(commands) and commands[pending].execute_time_ns - lead_ns <= t:
            ack = vehicle.receive(commands[pending])
            rejected += ack.stage is CommandStage.REJECTED
            pending += 1
        t = min(t + step_ns, end_ns)
        acks, more = vehicle.advance_to(t)
        rejected += sum(a.stage is CommandStage.REJECTED for a in acks)
        frames += more
        if len(frames) >= BATCH or t >= end_ns:
            for name, v in evaluator.values(frames).items():
                chunks[name].append(v)
            frames = []
        if progress is not None:
            progress((t - epoch_ns) / (end_ns - epoch_ns))
    values = {name: np.concatenate(parts) for name, parts in chunks.items()}
    return NominalFlight(
        seed=seed,
        values=values,
        rejected=rejected,
        frames=int(values["body_rate_degps"].shape[0]),
        duration_s=plan.duration_s,
    )


@dataclass(frozen=True)
class QuantityRow:
    """One quantity: its nominal worst (None: not measured), the channel it was on, and
    each band's threshold with its margin (threshold / worst for "high", worst /
    threshold for "low": above 1 where the band is clear of the nominal)."""

    quantity: str
    unit: str
    direction: str
    safing: bool
    nominal: float | None
    channel: str
    per_seed: tuple[float, ...]
    bands: dict[str, float] = field(default_factory=dict)
    source: str = "flown"

    @property
    def margins(self) -> dict[str, float | None]:
        out: dict[str, float | None] = {}
        for severity, threshold in self.bands.items():
            worst = self.nominal
            if worst is None or not math.isfinite(worst):
                out[severity] = None
            elif self.direction == "high":
                out[severity] = math.inf if worst <= 0.0 else threshold / worst
            else:
                out[severity] = math.inf if threshold <= 0.0 else worst / threshold
        return out

    @property
    def clear(self) -> bool | None:
        """Whether the nominal worst is outside every band (None: not measured)."""
        if self.nominal is None or not math.isfinite(self.nominal):
            return None
        least = next(iter(self.bands.values()))
        return self.nominal < least if self.direction == "high" else self.nominal > least

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: a value that is not finite (no nominal, a margin over 0) is None."""
        return {
            "quantity": self.quantity,
            "unit": self.unit,
            "direction": self.direction,
            "safing": self.safing,
            "nominal": _finite(self.nominal),
            "nominal_source": self.source,
            "channel": self.channel,
            "per_seed": [_finite(v) for v in self.per_seed],
            "bands": dict(self.bands),
            "margins": {k: _finite(v) for k, v in self.margins.items()},
            "clear": self.clear,
        }


def _finite(value: float | None) -> float | None:
    return value if value is not None and math.isfinite(value) else None


def limits_table(
    description: RobotDescription,
    flights: Sequence[NominalFlight] = (),
    *,
    link: LinkNominal | None = None,
) -> list[QuantityRow]:
    """One row per quantity of the robot's limits: the worst over ``flights`` (none: not
    measured) and, for the link quantities, :func:`link_nominal`."""
    links = link_nominal(link) if flights else {}
    rows = []
    for name, spec in QUANTITIES.items():
        bands = description.limits.get(name)
        if bands is None:
            continue
        channels = channel_names(name, description.n_joints, len(description.model.wheels))
        nominal: float | None = None
        channel = ""
        per_seed: tuple[float, ...] = ()
        source = "flown"
        if spec.source == "frame" and flights:
            worst = [f.worst(name) for f in flights]
            per_seed = tuple(w for w, _ in worst)
            measured = [w for w in worst if not math.isnan(w[0])]
            if measured:
                value, index = (max if spec.direction == "high" else min)(
                    measured, key=lambda w: w[0]
                )
                nominal, channel = value, channels[index]
        elif name in links:
            nominal, source = links[name], "computed"
        rows.append(
            QuantityRow(
                quantity=name,
                unit=spec.unit,
                direction=spec.direction,
                safing=spec.safing,
                nominal=nominal,
                channel=channel,
                per_seed=per_seed,
                bands=bands.to_dict(),
                source=source,
            )
        )
    return rows


def format_table(rows: Sequence[QuantityRow]) -> str:
    """The rows as a text table: quantity, nominal worst, and each band with its margin."""
    lines = [
        f"{'quantity':<26} {'dir':<4} {'nominal worst':>22}  bands (threshold, margin x nominal)"
    ]
    for row in rows:
        if row.nominal is None:
            nominal = "-"
        else:
            where = f" {row.channel}" if row.channel else ""
            tag = " (computed)" if row.source == "computed" else ""
            nominal = f"{row.nominal:.4g}{where}{tag}"
        margins = row.margins
        bands = []
        for severity, threshold in row.bands.items():
            m = margins[severity]
            shown = "" if m is None else f" x{m:.2g}"
            red = "*" if row.safing and severity in ("critical", "severe") else ""
            bands.append(f"{severity}{red} {threshold:g}{shown}")
        unit = f"[{row.unit}]"
        lines.append(
            f"{row.quantity:<26} {row.direction:<4} {nominal:>22}  {unit} " + ", ".join(bands)
        )
    lines.append("* red limit of a safing quantity: the vehicle safes itself on it")
    return "\n".join(lines)
