"""``hikoboshi``: the command line."""

from __future__ import annotations

import contextlib
import json
import logging
import sys
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Annotated, Any, NoReturn

import numpy as np
import typer
from rich import box
from rich.markup import escape
from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn
from rich.table import Table

from hikoboshi import limits_cli, post_cli, robot_cli, windows_cli
from hikoboshi.output import HELP_MARKUP, make_console

#: The top-level help (the module docstring is for readers of the code).
HELP = (
    "Hikoboshi, the ground system for the ETS-VII space robot: plan experiments, fly them "
    "against the simulated spacecraft through the ground service, and analyse, report and "
    "export the passes. Commands that report something take --json."
)

app = typer.Typer(
    rich_markup_mode=HELP_MARKUP, no_args_is_help=True, add_completion=False, help=HELP
)
model_app = typer.Typer(
    rich_markup_mode=HELP_MARKUP,
    no_args_is_help=True,
    help="The robot model (ETS-VII or --robot FILE): export and quantities.",
)
app.add_typer(model_app, name="model")
limits_cli.register(model_app)  # model limits
post_cli.register(app)  # report, mcap export|import, export telemetry
windows_cli.register(app)  # windows
robot_cli.register(app)  # robot check

console = make_console()
err_console = make_console(stderr=True)


def _fail(reason: str) -> NoReturn:
    """One line on stderr, exit status 2."""
    err_console.print(f"error: {reason}", markup=False, highlight=False, soft_wrap=True)
    raise typer.Exit(code=2)


LogFormatOption = Annotated[
    str,
    typer.Option(
        envvar="HIKOBOSHI_LOG_FORMAT",
        help="Log lines as text or json (one object a line); docs/operations.md, Logs",
    ),
]
LogLevelOption = Annotated[
    str,
    typer.Option(
        envvar="HIKOBOSHI_LOG_LEVEL", help="Least level logged: debug, info, warning, error"
    ),
]


FoxglovePortOption = Annotated[
    int | None,
    typer.Option(
        help="Stream the live pass to Foxglove on this port (ws://HOST:PORT, docs/mcap.md); "
        "needs the hikoboshi[foxglove] extra",
        show_default=False,
    ),
]


def _check_foxglove(port: int) -> None:
    """One error line and status 2 for a port out of range or the extra missing."""
    from server.services.foxglove_live import foxglove_missing

    if not 0 <= port <= 65535:
        _fail(f"--foxglove-port {port} must lie in [0, 65535]")
    missing = foxglove_missing()
    if missing is not None:
        _fail(f"--foxglove-port: {missing}")


def _configure_logging(log_format: str, log_level: str, stream: Any = None) -> None:
    """The one logging configuration (server/logs.py), or one error line and status 2."""
    from server.logs import configure_logging

    try:
        configure_logging(log_format, log_level, stream=stream)
    except ValueError as exc:
        _fail(str(exc))


RobotOption = Annotated[
    Path | None,
    typer.Option(
        "--robot",
        help="Robot description (TOML, docs/robots.md); default: ETS-VII as built in.",
    ),
]


def _load(robot: Path) -> Any:
    """The robot description at ``robot``, or one error line and exit status 2."""
    from planner.description import load_robot
    from planner.errors import PlannerError

    try:
        return load_robot(robot)
    except PlannerError as exc:
        _fail(str(exc))


def _robot(robot: Path | None) -> tuple[str, Any]:
    """The robot's name and RobotModel: from ``robot``, or ETS-VII's built-in model."""
    from planner.model import default_model

    if robot is None:
        return "ets7", default_model()
    description = _load(robot)
    return description.name, description.model


@model_app.command("urdf")
def model_urdf(robot: RobotOption = None) -> None:
    """Print the model as URDF (base, arm and a hand link); its root link is the base."""
    from planner.model import default_model
    from planner.urdf import urdf_xml

    if robot is None:
        sys.stdout.write(urdf_xml(default_model()))
        return
    description = _load(robot)
    box = description.base_box_size_m
    extra = {} if box is None else {"base_box_size_m": box}
    sys.stdout.write(urdf_xml(description.model, name=description.name, **extra))


@model_app.command("mjcf")
def model_mjcf(robot: RobotOption = None) -> None:
    """Print the MuJoCo model (MJCF) the simulator steps."""
    from planner.mjcf import mjcf_xml

    name, model = _robot(robot)
    sys.stdout.write(mjcf_xml(model, name=name))


def _parse_joints_deg(text: str, n: int) -> np.ndarray:
    parts = [p.strip() for p in text.split(",")]
    if len(parts) != n:
        _fail(f"--joints-deg needs {n} comma-separated angles, got {len(parts)}: {text!r}")
    values = []
    for i, part in enumerate(parts):
        try:
            value = float(part)
        except ValueError:
            _fail(f"--joints-deg value {i + 1} is not a number: {part!r}")
        if not np.isfinite(value):
            _fail(f"--joints-deg value {i + 1} is not finite: {part!r}")
        values.append(value)
    return np.array(values)


def quantities_document(joints_deg: np.ndarray, model: Any = None) -> dict[str, Any]:
    """The JSON object of ``hikoboshi model quantities`` (base at nominal, zero momentum);
    ``model`` is a RobotModel (default: ETS-VII)."""
    from planner.dynamics import DynamicsWorkspace
    from planner.frames import rpy_from_matrix
    from planner.model import default_model
    from planner.state import State

    model = default_model() if model is None else model
    joints_rad = model.check_joints(np.radians(joints_deg))
    zero_rates = np.zeros(model.n_joints)
    q = DynamicsWorkspace(model).evaluate(
        State(joints_rad=joints_rad, joint_rates_radps=zero_rates)
    )
    return {
        "joints_deg": joints_deg.tolist(),
        "total_mass_kg": q.total_mass_kg,
        "hand_position_robot_m": q.hand.pos_robot_m.tolist(),
        "hand_rpy_deg": np.degrees(rpy_from_matrix(q.hand.rot_robot_from_hand)).tolist(),
        "generalized_jacobian": q.J_g.tolist(),
        "base_reaction_map": q.reaction_map.tolist(),
        "system_inertia_com_kgm2": q.inertia_com_orbit_kgm2.tolist(),
        "gravity_gradient_torque_nm": q.gravity_gradient_torque_base_nm.tolist(),
    }


@model_app.command("quantities")
def model_quantities(
    joints_deg: Annotated[
        str,
        typer.Option(
            "--joints-deg",
            help="One angle per joint in degrees, comma-separated: J1,J2,...,Jn (six for ETS-VII)",
        ),
    ],
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    robot: RobotOption = None,
) -> None:
    """Planning quantities at one arm pose, base at the orbit frame's nominal attitude."""
    from planner.errors import PlannerError

    name, model = _robot(robot)
    values = _parse_joints_deg(joints_deg, model.n_joints)
    try:
        doc = quantities_document(values, model)
    except PlannerError as exc:
        _fail(str(exc))
    if as_json:
        sys.stdout.write(json.dumps(doc) + "\n")
        return
    title = "ETS-VII" if robot is None else name
    table = Table(title=f"{title} at joints {joints_deg} deg")
    table.add_column("quantity")
    table.add_column("value")
    for key, value in doc.items():
        table.add_row(key, json.dumps(np.round(np.asarray(value), 6).tolist()))
    console.print(table)


def _plan_help() -> str:
    from hikoboshi.planning_cli import parameters_help

    return (
        "Plan an experiment (ptp, reactionless, gjm, coordination, nonholonomic, pass) as a "
        "4 Hz time-tagged command plan with its prediction, and write it as JSON; or a "
        "campaign of passes over a mission's windows (plan campaign --mission FILE --start "
        "ISO8601; docs/missions.md). Parameters "
        "are set with --set NAME=VALUE (tuples comma-separated); the defaults reproduce the "
        "paper's experiment. With --robot FILE the plan is for that robot: its poses, and "
        "its [experiments.NAME] tables as the defaults.\n\nParameters:\n\n" + parameters_help()
    )


@app.command("plan", help=_plan_help())
def plan_command(
    experiment: Annotated[
        str,
        typer.Argument(
            help="ptp, reactionless, gjm, coordination, nonholonomic or pass; or check, to "
            "evaluate a stored plan FILE against the flight rules"
        ),
    ],
    file: Annotated[
        Path | None, typer.Argument(help="check: the plan JSON file to evaluate.")
    ] = None,
    out: Annotated[
        Path | None,
        typer.Option("--out", help="Plan JSON file to write (planning); campaign: a directory."),
    ] = None,
    assignments: Annotated[
        list[str] | None, typer.Option("--set", help="NAME=VALUE, repeatable.")
    ] = None,
    optimise_offset_flag: Annotated[
        bool,
        typer.Option(
            "--optimise-offset",
            help="coordination: optimise the offset size and switch times in the closed loop.",
        ),
    ] = False,
    as_json: Annotated[
        bool, typer.Option("--json", help="Print the metrics and the rules as JSON.")
    ] = False,
    robot: RobotOption = None,
    mission_file: Annotated[
        Path | None, typer.Option("--mission", help="campaign: the mission file (TOML).")
    ] = None,
    start: Annotated[
        str | None, typer.Option("--start", help="campaign: from when, ISO 8601 with offset.")
    ] = None,
    assignment: Annotated[
        str | None,
        typer.Option(
            "--assign",
            help="campaign: experiments per pass, passes split by / (default "
            "ptp,reactionless,gjm/coordination/nonholonomic).",
        ),
    ] = None,
) -> None:
    """Plan (exit 3 when the plan fails a flight rule: the file is still written, with its
    rules table, so that it can be looked at), or ``plan check FILE``, or ``plan campaign
    --mission FILE --start ISO8601 [--out DIR]``: one plan per pass over consecutive windows
    and a campaign.json (docs/missions.md)."""
    if experiment == "campaign":
        from hikoboshi.campaign_cli import run_campaign

        if file is not None:
            _fail(f"unexpected argument {str(file)!r} (plan campaign takes no FILE)")
        if assignments or optimise_offset_flag:
            _fail("plan campaign takes no --set or --optimise-offset (it plans the defaults)")
        run_campaign(
            mission_file=mission_file,
            start=start,
            out=out,
            robot=_load(robot) if robot is not None else None,
            assignment=assignment,
            as_json=as_json,
        )
        return
    if mission_file is not None or start is not None or assignment is not None:
        _fail("--mission, --start and --assign are for plan campaign")
    if experiment == "check":
        if file is None:
            _fail("plan check needs the plan FILE to evaluate")
        _plan_check(file, robot, as_json=as_json)
        return
    if file is not None:
        _fail(f"unexpected argument {str(file)!r} (only plan check takes a FILE)")
    if out is None:
        _fail("give --out FILE: where to write the plan")
    from hikoboshi.planning_cli import make_plan, write_atomically
    from planner.errors import PlannerError

    description = _load(robot) if robot is not None else _default_description()
    try:
        status = (
            contextlib.nullcontext()
            if as_json
            else console.status(f"planning {experiment}", spinner="dots")
        )
        with status:
            plan = make_plan(
                experiment,
                assignments or [],
                optimise_offset_flag=optimise_offset_flag,
                robot=None if robot is None else description,
            )
        if not as_json:
            status = console.status("checking the flight rules", spinner="dots")
        with status:
            plan, report = description.checked(plan)
    except PlannerError as exc:
        _fail(str(exc))
    write_atomically(out, plan.to_json())
    if as_json:
        sys.stdout.write(
            json.dumps({"out": str(out), "metrics": dict(plan.metrics), **_rules_summary(report)})
            + "\n"
        )
        _exit_on_rules(report, quiet=True)
        return
    table = Table(
        title=f"{experiment}: {plan.command_times_s.size} commands, {plan.duration_s:.2f} s"
    )
    table.add_column("segment")
    table.add_column("kind")
    table.add_column("from s", justify="right")
    table.add_column("to s", justify="right")
    for seg in plan.segments:
        table.add_row(seg.name, seg.kind, f"{seg.t_start_s:.2f}", f"{seg.t_end_s:.2f}")
    console.print(table)
    metrics = Table(title="metrics")
    metrics.add_column("name")
    metrics.add_column("value", justify="right")
    for key, value in plan.metrics.items():
        metrics.add_row(key, f"{value:.6g}")
    console.print(metrics)
    _print_rules(report)
    console.print(f"wrote {out}" + ("" if report.passed else " (it FAILS the flight rules)"))
    _exit_on_rules(report, quiet=False)


def _default_description() -> Any:
    """ETS-VII's description file (its collision geometry and flight rules)."""
    from planner.description import default_robot
    from planner.errors import PlannerError

    try:
        return default_robot()
    except PlannerError as exc:
        _fail(str(exc))


def _description_for(plan: Any, robot: Path | None) -> Any:
    """The description ``plan`` was made for: ``robot`` if given (it must be the one), else
    the shipped description whose content hash the plan records."""
    from planner.description import EXAMPLES_DIR, load_robot
    from planner.errors import PlannerError

    if robot is not None:
        description = _load(robot)
    else:
        description = None
        for path in sorted(EXAMPLES_DIR.glob("*/*.toml")):
            try:
                candidate = load_robot(path)
            except PlannerError:
                continue
            if candidate.content_sha256 == plan.robot_hash:
                description = candidate
                break
        if description is None:
            _fail(
                f"the plan is for robot {plan.robot!r} (description {plan.robot_hash[:12]}), "
                "which is not shipped: give its description with --robot FILE"
            )
    if description.content_sha256 != plan.robot_hash:
        _fail(
            f"the plan is for robot {plan.robot!r} (description {plan.robot_hash[:12]}), not "
            f"{description.name!r} ({description.content_sha256[:12]})"
        )
    return description


def _plan_check(file: Path, robot: Path | None, *, as_json: bool) -> None:
    from planner.errors import PlannerError
    from planner.plan import Plan

    try:
        plan = Plan.from_json(file.read_text(encoding="utf-8"))
    except OSError as exc:
        _fail(f"{file}: {exc.strerror}")
    except (PlannerError, UnicodeDecodeError) as exc:
        _fail(f"{file}: {exc}")
    description = _description_for(plan, robot)
    try:
        status = (
            contextlib.nullcontext()
            if as_json
            else console.status("checking the flight rules", spinner="dots")
        )
        with status:
            report = description.check_plan(plan)
    except PlannerError as exc:
        _fail(str(exc))
    if as_json:
        sys.stdout.write(json.dumps({"plan": str(file), **_rules_summary(report)}) + "\n")
    else:
        console.print(
            f"{file}: {plan.experiment} for {plan.robot}, {plan.duration_s:.2f} s", highlight=False
        )
        _print_rules(report)
    _exit_on_rules(report, quiet=as_json)


def _rules_summary(report: Any) -> dict[str, Any]:
    """The rules for --json: the verdict and every row (not the clearance trace)."""
    return {
        "flight_rules": {
            "passed": report.passed,
            "rows": [row.to_dict() for row in report.rows],
            "step_s": report.step_s,
            "n_samples": report.n_samples,
            "n_pairs": report.n_pairs,
            "n_queries": report.n_queries,
        }
    }


def _print_rules(report: Any) -> None:
    table = Table(
        title=f"flight rules ({report.n_pairs} body pairs at a {report.step_s:.4g} s step)"
    )
    for column, justify in (
        ("rule", "left"),
        ("worst", "right"),
        ("limit", "right"),
        ("verdict", "left"),
        ("at s", "right"),
        ("where", "left"),
    ):
        table.add_column(column, justify=justify)  # type: ignore[arg-type]
    for row in report.rows:
        relation = ">=" if row.bound == "min" else "<="
        where = " / ".join(row.bodies) if row.bodies is not None else row.detail
        table.add_row(
            row.rule,
            f"{row.value:.4g} {row.unit}",
            f"{relation} {row.limit:.4g}",
            "[green]pass[/green]" if row.passed else "[bold red]FAIL[/bold red]",
            "" if row.t_s is None else f"{row.t_s:.2f}",
            escape(where),
        )
    console.print(table)


def _exit_on_rules(report: Any, *, quiet: bool) -> None:
    """Exit status 3 when a rule fails, naming each failing row on stderr."""
    if report.passed:
        return
    if not quiet:
        for row in report.failing:
            err_console.print(
                f"flight rule failed: {escape(row.describe())}", highlight=False, soft_wrap=True
            )
    raise typer.Exit(code=3)


@app.command()
def demo(
    out: Annotated[Path, typer.Option(help="Where the database, logs and summary go.")] = Path(
        "out/demo"
    ),
    speed: Annotated[float, typer.Option(help="Onboard seconds per wall second.")] = 20.0,
    loss: Annotated[float, typer.Option(help="Relay message loss probability [0, 1).")] = 0.0,
    outage: Annotated[
        list[str] | None,
        typer.Option(
            help="LOS window START:END, onboard s from the spacecraft's start; repeatable"
        ),
    ] = None,
    port: Annotated[int, typer.Option(help="Ground service port (a free one if taken).")] = 8000,
    seed: Annotated[int, typer.Option(help="Seed for the relay and the sensors.")] = 0,
    experiments: Annotated[
        str | None,
        typer.Option(
            help="Comma-separated subset of ptp,reactionless,gjm,coordination,"
            "nonholonomic (default: the whole schedule)"
        ),
    ] = None,
    serve_after: Annotated[
        bool, typer.Option("--serve-after", help="Keep the service up afterwards (Ctrl-C).")
    ] = False,
    as_json: Annotated[bool, typer.Option("--json", help="Print only the JSON summary.")] = False,
    robot: RobotOption = None,
    fault: Annotated[
        list[str] | None,
        typer.Option(
            help="A fault for the spacecraft, NAME@T[,key=value...], T in onboard s from the "
            "spacecraft's start (as --outage): jointN-stuck, jointN-drift[,rate_degps=], "
            "wheelN-fail, attitude-bias[,deg=][,axis=], bump[,nms=][,axis=]; repeatable "
            "(docs/spacecraft.md)"
        ),
    ] = None,
    campaign: Annotated[
        bool,
        typer.Option(
            "--campaign",
            help="Fly the mission's campaign: its passes back to back across the computed "
            "windows, the gaps flown fast (docs/missions.md)",
        ),
    ] = False,
    mission: Annotated[
        Path | None,
        typer.Option(
            help="The campaign's mission file (implies --campaign; default "
            "examples/missions/ets7-1999.toml)"
        ),
    ] = None,
    start: Annotated[
        str, typer.Option(help="With --campaign: the campaign's start, ISO 8601 UTC")
    ] = "1999-09-30T00:00:00Z",
    log_format: LogFormatOption = "text",
    log_level: LogLevelOption = "info",
    foxglove_port: FoxglovePortOption = None,
) -> None:
    """The main job: the ground service on SQLite, the simulated spacecraft as its own
    process, and the whole ETS-VII pass (all four experiments) at --speed times real time.
    With --robot FILE: that robot's whole pass, planned, flown and checked for it.

    The summary (OUT/summary.json) lists the pass's alarms and the vehicle's safing (the
    truth log, OUT/truth.jsonl, says what really happened). Exit status: without --fault,
    0 iff the pass ended complete with no frame missing (it also says how many alarms went
    above watch); with --fault, 0 iff the pass ended safed or complete, every fault began,
    no frame is missing, no command is outstanding and none executed after the vehicle
    safed; 1 otherwise; 2 for bad options."""
    from server.redaction import install_redaction
    from spacecraft.link import parse_outage

    install_redaction()  # no token in any log of the demo (docs/security.md "Logs")
    from server.logs import check_log_options

    # Bad options are refused before the ground service's modules (hikoboshi.demo: uvicorn,
    # the application) are imported: seconds of a refusal's time.
    try:
        check_log_options(log_format, log_level)
    except ValueError as exc:
        _fail(str(exc))

    if foxglove_port is not None:
        _check_foxglove(foxglove_port)
    if not 0 < speed <= 1000:
        _fail(f"--speed {speed} must lie in (0, 1000]")
    if not 0 <= loss < 1:
        _fail(f"--loss {loss} must lie in [0, 1)")
    for window in outage or []:
        try:
            parse_outage(window)
        except ValueError as exc:
            _fail(f"--outage {window}: {exc}")
    if campaign or mission is not None:
        if outage or fault or robot is not None or experiments or serve_after:
            _fail(
                "--campaign takes its windows and experiments from the mission: no --outage, "
                "--fault, --robot, --experiments or --serve-after"
            )
        _campaign_demo(mission, start, out, speed, loss, port, seed, as_json, log_format, log_level)
        return
    chosen = tuple(e.strip() for e in experiments.split(",") if e.strip()) if experiments else ()
    if robot is not None:
        _load(robot)  # a bad description: one error line before anything starts
    from hikoboshi.demo import DemoError, DemoOptions, check_fault_specs, run_demo

    try:
        check_fault_specs(fault or (), robot)
    except DemoError as exc:
        _fail(str(exc))
    options = DemoOptions(
        faults=tuple(fault or ()),
        robot=robot,
        out=out,
        speed=speed,
        loss=loss,
        outages=tuple(outage or ()),
        port=port,
        seed=seed,
        experiments=chosen,
        serve_after=serve_after,
        on_ready=None if as_json else _announce,
        log_format=log_format,
        log_level=log_level.lower(),
        foxglove_port=foxglove_port,
    )
    out.mkdir(parents=True, exist_ok=True)
    if foxglove_port is not None and not as_json:
        console.print(f"Foxglove live view: ws://127.0.0.1:{foxglove_port}")
    ground_log = (out / "ground.log").open("a", encoding="utf-8")  # open until the exit
    _configure_logging(log_format, log_level, stream=ground_log)
    with _phase_bars(as_json, {"pass": "pass (onboard s)"}) as on_progress:
        try:
            summary = run_demo(options, on_progress)
        except DemoError as exc:
            _fail(f"demo stopped: {exc} (logs in {out})")
    if as_json:
        sys.stdout.write(json.dumps(summary) + "\n")
    else:
        _print_demo(summary)
    if not summary["verdict"]["ok"]:
        raise typer.Exit(1)


def _campaign_demo(
    mission: Path | None,
    start: str,
    out: Path,
    speed: float,
    loss: float,
    port: int,
    seed: int,
    as_json: bool,
    log_format: str,
    log_level: str,
) -> None:
    """``hikoboshi demo --campaign``: exit 0 iff every pass ended complete with every
    command executed at its tag, none expired, no frame missing, and no command reached
    the spacecraft outside a window; 1 otherwise; 2 for bad options."""
    from hikoboshi.campaign_demo import CampaignOptions, campaign_markdown, run_campaign_demo
    from hikoboshi.demo import DemoError
    from mission import MISSIONS_DIR, MissionError, load_mission, parse_utc

    path = mission if mission is not None else MISSIONS_DIR / "ets7-1999.toml"
    try:
        load_mission(path)
        start_utc = parse_utc(start)
    except MissionError as exc:
        _fail(str(exc))
    options = CampaignOptions(
        mission=path,
        start_utc=start_utc,
        out=out if out != Path("out/demo") else Path("out/campaign"),
        speed=speed,
        loss=loss,
        port=port,
        seed=seed,
        log_format=log_format,
        log_level=log_level.lower(),
    )
    options.out.mkdir(parents=True, exist_ok=True)
    ground_log = (options.out / "ground.log").open("a", encoding="utf-8")  # open until exit
    _configure_logging(log_format, log_level, stream=ground_log)
    with _phase_bars(as_json) as on_progress:
        try:
            doc = run_campaign_demo(options, on_progress)
        except (DemoError, MissionError) as exc:
            _fail(f"campaign demo stopped: {exc} (logs in {options.out})")
    if as_json:
        sys.stdout.write(json.dumps(doc) + "\n")
    else:
        console.print(campaign_markdown(doc), highlight=False, soft_wrap=True, markup=False)
        console.print(f"Campaign report: {options.out}/campaign.json and campaign.md")
    if not doc["verdict"]["ok"]:
        raise typer.Exit(1)


@contextlib.contextmanager
def _phase_bars(
    as_json: bool, labels: dict[str, str] | None = None
) -> Iterator[Callable[[str, float, float], None]]:
    """A progress bar per phase on stderr (none with --json): the demos' ``on_progress``."""
    with Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        TextColumn("{task.completed:.0f}/{task.total:.0f}"),
        TimeRemainingColumn(),
        console=err_console,
        disable=as_json,
    ) as progress:
        tasks: dict[str, Any] = {}

        def on_progress(phase: str, done: float, total: float) -> None:
            if phase not in tasks:
                tasks[phase] = progress.add_task((labels or {}).get(phase, phase), total=total)
            progress.update(tasks[phase], completed=done, total=total)

        yield on_progress


def _announce(console_url: str, tokens_file: Path) -> None:
    # Where the tokens are, never the tokens: what is printed ends up in logs.
    err_console.print(
        f"Ground service up: console {console_url} (sign in with the demo-viewer or the "
        f"demo-operator token from {tokens_file}, token=name:role,...); API docs "
        f"{console_url}docs"
    )


def _print_demo(summary: dict[str, Any]) -> None:
    keys = (
        "frames_expected",
        "frames_stored",
        "frames_missing",
        "gaps_open",
        "duplicates_dropped",
        "duplicates_stored",
        "commands_sent",
        "commands_executed",
        "commands_executed_at_tag",
        "commands_rejected",
        "commands_expired",
        "commands_cancelled",
        "commands_retransmitted",
        "commands_outstanding",
        "commands_unresolved",
        "min_command_lead_s",
        "outcome",
    )
    title = f"{summary['name']}: {summary['final_state']}, {summary.get('outcome')}"
    table = Table(title=title)
    table.add_column("")
    table.add_column("")
    for key in keys:
        table.add_row(key, str(summary.get(key)))
    console.print(table)
    console.print(json.dumps({k: summary.get(k) for k in keys}))
    _print_alarms(summary)
    _print_safing(summary)
    for note in summary["verdict"]["notes"]:
        console.print(note, highlight=False, soft_wrap=True)
    for problem in summary["verdict"]["problems"]:
        err_console.print(f"not sound: {problem}", highlight=False, soft_wrap=True)
    console.print(f"Report: {summary['report_html']} (and report.json)")
    console.print(f"Recording (MCAP, opens in Foxglove): {summary['recording_mcap']}")
    if summary["analyses_failed"]:
        console.print(f"Analyses that failed (see the report): {summary['analyses_failed']}")
    console.print(f"Summary: {summary['database'].rsplit('/', 1)[0]}/summary.json")
    console.print(f"Database: {summary['database']}")
    console.print(f"To browse it again: {summary['serve_again']}")


def _s(value: float | None) -> str:
    """Onboard s since the spacecraft's start, or blank where the demo could not say."""
    return "" if value is None else f"{value:.2f}"


def _print_alarms(summary: dict[str, Any]) -> None:
    alarms = summary["alarms"]
    if not alarms["items"]:
        return
    table = Table(
        title=f"Alarms: {alarms['above_watch']} above watch (onboard s from the spacecraft's "
        "start; raised: the frame's time, then the ground's)",
        box=box.SIMPLE_HEAD,
    )
    table.add_column("alarm", no_wrap=True)  # a quantity's name unbroken
    for column in ("limit", "trigger\nworst", "raised"):
        table.add_column(column)
    table.add_column("bands crossed", no_wrap=True)
    for a in alarms["items"]:
        unit = f" {a['unit']}" if a["unit"] else ""
        table.add_row(
            escape("\n".join(p for p in (a["quantity"], a["channel"]) if p)) + f"\n{a['severity']}",
            "" if a["limit"] is None else f"{a['limit']:.4g}{unit}",
            f"{_g(a['trigger_value'])}\n{_g(a['worst_value'])}",
            f"{_s(a['raised_frame_s']) or '-'}\n{_s(a['raised_ground_s']) or '-'}",
            "\n".join(f"{band} {_s(t)}" for band, t in a["crossings"].items()),
        )
    console.print(table)


def _g(value: float | None) -> str:
    return "-" if value is None else f"{value:.4g}"


def _print_safing(summary: dict[str, Any]) -> None:
    safing = summary["safing"]
    if not safing["safed"] and not safing["truth_faults"]:
        return
    table = Table(
        title="Faults and safing (onboard s from the spacecraft's start)", box=box.SIMPLE_HEAD
    )
    table.add_column("what")
    table.add_column("onboard s")
    table.add_column("")
    for fault in safing["truth_faults"]:
        table.add_row("fault (truth)", _s(fault["onboard_s"]), escape(fault["spec"]))
    for entry in safing["truth_safing"]:
        what = "SAFE entered (truth)" if entry["event"] == "safing_entry" else "SAFE left (truth)"
        where = " ".join(str(entry.get(k) or "") for k in ("quantity", "channel")).strip()
        table.add_row(what, _s(entry["onboard_s"]), escape(where))
    if safing["safed"]:
        trigger = safing["trigger"] or {}
        where = " ".join(str(trigger.get(k) or "") for k in ("quantity", "channel")).strip()
        table.add_row("SAFE (vehicle's report)", _s(safing["since_s"]), escape(where))
        table.add_row("ground heard it", _s(safing["ground_heard_s"]), "")
        table.add_row("pass ended (ground)", _s(safing["pass_ended_s"]), "")
        table.add_row("commands dropped on board", "", str(safing["cancelled_on_board"]))
        table.add_row(
            "commands executed after safing", "", str(safing["commands_executed_after_safing"])
        )
    table.add_row("pass", "", escape(f"{safing['pass_state']}: {safing['pass_reason'] or ''}"))
    table.add_row("vehicle mode at the end", "", str(safing["vehicle_mode"]))
    console.print(table)


@app.command("ptp-demo")
def ptp_demo(
    out: Annotated[Path, typer.Option(help="Where to write the results.")] = Path("out/ptp-demo"),
    as_json: Annotated[bool, typer.Option("--json", help="Print only the JSON summary.")] = False,
) -> None:
    """Simulate PTP A->B on the free-floating model (no ground, no link) and report the
    base's attitude response against the eq. (10) prediction."""
    from hikoboshi import foundation_demo

    with Progress(
        TextColumn("[bold]PTP A->B, free drift"),
        BarColumn(),
        TextColumn("{task.completed:.0f}/{task.total:.0f} s simulated"),
        TimeRemainingColumn(),
        console=err_console,
        disable=as_json,
    ) as progress:
        task = progress.add_task("sim", total=1.0)

        def on_progress(t_s: float, end_s: float) -> None:
            progress.update(task, completed=t_s, total=end_s)

        summary = foundation_demo.run(out, on_progress=on_progress)
    if as_json:
        sys.stdout.write(json.dumps(summary) + "\n")
        return
    table = Table(title="Base attitude after PTP A->B (roll, pitch, yaw in deg)")
    table.add_column("")
    table.add_column("roll")
    table.add_column("pitch")
    table.add_column("yaw")
    for label, key in (
        ("simulated (MuJoCo, lagging servos)", "simulated_final_rpy_deg"),
        ("predicted (eq. 10, ideal tracking)", "predicted_final_rpy_deg"),
        ("peak |excursion|", "peak_rpy_deg"),
    ):
        table.add_row(label, *(f"{v:+.4f}" for v in summary[key]))
    console.print(table)
    console.print(
        f"joints at B: {summary['joints_b_deg']} deg; motion {summary['motion_duration_s']} s, "
        f"{summary['commands']} commands at 4 Hz; max servo lag per joint "
        f"{summary['max_servo_lag_deg']} deg; angular momentum drift "
        f"{summary['angular_momentum_drift_nms']:.2e} N m s"
    )
    console.print(f"Look at: {summary['summary_json']} and {summary['series_csv']}")


@app.command()
def spacecraft(
    ground: Annotated[
        list[str],
        typer.Option(
            help="Ground link endpoint, ws://HOST:PORT/PATH; repeat it for a hot standby's "
            "(tried in order after a drop or a standby's refusal)"
        ),
    ],
    token: Annotated[
        str | None,
        typer.Option(
            envvar="HIKOBOSHI_SPACECRAFT_TOKEN",
            show_envvar=True,
            help="API token with the spacecraft role (better from the environment or "
            "--token-file: a command line is visible to every user of the host)",
        ),
    ] = None,
    token_file: Annotated[
        Path | None,
        typer.Option(
            envvar="HIKOBOSHI_SPACECRAFT_TOKEN_FILE",
            show_envvar=True,
            help="A file holding the token (a container secret)",
        ),
    ] = None,
    time_scale: Annotated[float, typer.Option(help="Onboard seconds per wall second")] = 1.0,
    delay: Annotated[float | None, typer.Option(help="One-way delay, s (both directions)")] = None,
    jitter: Annotated[float | None, typer.Option(help="Delay jitter, s (1 sigma)")] = None,
    loss: Annotated[float | None, typer.Option(help="Message loss probability [0, 1)")] = None,
    outage: Annotated[
        list[str] | None, typer.Option(help="LOS window START:END in onboard s; repeatable")
    ] = None,
    bandwidth: Annotated[float | None, typer.Option(help="Link bandwidth cap, bytes/s")] = None,
    link_config: Annotated[
        Path | None, typer.Option(help="TOML file with [link], [uplink], [downlink] tables")
    ] = None,
    garbage: Annotated[
        list[str] | None,
        typer.Option(
            help="Noise toward the ground START:END:RATE: malformed messages (invalid JSON, "
            "unknown types, wrong versions, malformed telemetry, in turn) at RATE per wall "
            "second while the onboard clock is in [START, END) s (as --outage); repeatable "
            "(docs/protocol.md, Malformed messages)"
        ),
    ] = None,
    telemetry_rate_hz: Annotated[float, typer.Option(help="Telemetry frames per second")] = 10.0,
    seed: Annotated[int, typer.Option(help="Seed for link and sensor noise")] = 0,
    los_policy: Annotated[
        str,
        typer.Option(
            help="Silence from the ground: 'continue' the loaded schedule, or 'hold' the arm "
            "(refuse queued joint commands) after --los-hold-after seconds"
        ),
    ] = "continue",
    los_hold_after: Annotated[
        float | None, typer.Option(help="Onboard seconds of silence before 'hold' holds the arm")
    ] = None,
    acs_config: Annotated[
        Path | None,
        typer.Option(
            help="TOML file with an acs table: the attitude-control law (bandwidth_radps, "
            "damping_ratio, integral_time_s, rate_filter_tau_s, dead_band_deg, "
            "torque_limit_nm, ...; docs/spacecraft.md); default the calibrated PD law (with "
            "--robot: the description's, whose keys the file's replace)"
        ),
    ] = None,
    robot: RobotOption = None,
    vehicle_config: Annotated[
        Path | None,
        typer.Option(
            help="TOML file with a servo and/or a sensor_noise table (a robot description's "
            "keys; hikoboshi calibrate --vehicle-out writes one): the joint servos and sensor "
            "noise flown, replacing the defaults (with --robot: the description's)"
        ),
    ] = None,
    fault: Annotated[
        list[str] | None,
        typer.Option(
            help="A fault injected in the truth simulation, NAME@T[,key=value...], T in onboard "
            "s from the start: jointN-stuck@T, jointN-drift@T[,rate_degps=0.5], wheelN-fail@T, "
            "attitude-bias@T[,deg=3.0][,axis=x], bump@T[,nms=10][,axis=x]; repeatable "
            "(docs/spacecraft.md)"
        ),
    ] = None,
    truth_log: Annotated[
        Path | None,
        typer.Option(
            help="Write the truth log here (JSON lines: each fault's onset, each entry into "
            "and exit from on-board safing; never sent to the ground)"
        ),
    ] = None,
    no_safing: Annotated[
        bool,
        typer.Option(
            "--no-safing",
            help="Fly without on-board safing (rehearse the ground's alarms with no on-board "
            "protection)",
        ),
    ] = False,
    mission: Annotated[
        Path | None,
        typer.Option(
            help="A mission file (docs/missions.md): the link is up only inside its contact "
            "windows and its one-way delay is the ground's processing delay plus the path's "
            "light time (replacing --delay); the gaps are flown fast"
        ),
    ] = None,
    mission_start: Annotated[
        str | None,
        typer.Option(
            help="With --mission: the UTC (ISO 8601) of the spacecraft's onboard second 0 "
            "(default: the mission's elements' epoch)"
        ),
    ] = None,
    windows: Annotated[
        Path | None,
        typer.Option(
            help="With --mission: fly these windows (hikoboshi windows --json, or a "
            "campaign.json) instead of every window of --hours from the start"
        ),
    ] = None,
    relay: Annotated[
        list[str] | None,
        typer.Option(help="With --mission: only this relay's windows; repeatable"),
    ] = None,
    hours: Annotated[
        float, typer.Option(help="With --mission and no --windows: hours of windows")
    ] = 24.0,
    fast_scale: Annotated[
        float | None,
        typer.Option(
            help="With --mission: between windows the onboard clock runs at most this many "
            "times wall time (default: as fast as the simulation computes)"
        ),
    ] = None,
    log_format: LogFormatOption = "text",
    log_level: LogLevelOption = "info",
) -> None:
    """Run the simulated spacecraft: the vehicle behind an emulated TDRS relay link. With
    --robot it flies that robot description (model, servos, attitude control, wheel limits,
    sensor noise, live limits) and names it, with its hash and joint count, in hello. The
    vehicle safes itself on a red limit unless --no-safing; --fault injects faults."""
    import asyncio
    import dataclasses
    import signal

    from server.redaction import install_redaction
    from spacecraft.faults import parse_fault
    from spacecraft.link import LinkConfig, load_link_config, parse_garbage, parse_outage
    from spacecraft.process import ProcessConfig, SpacecraftProcess
    from spacecraft.vehicle_config import VehicleConfig, vehicle_config_for

    install_redaction()  # its token never in its log (docs/security.md "Logs")
    _configure_logging(log_format, log_level)
    token = _spacecraft_token(token, token_file)
    try:
        if link_config is not None:
            up, down = load_link_config(link_config)
        else:
            up, down = LinkConfig(seed=seed), LinkConfig(seed=seed + 1)
        changes: dict[str, Any] = {}
        if delay is not None:
            changes["delay_s"] = delay
        if jitter is not None:
            changes["jitter_s"] = jitter
        if loss is not None:
            changes["loss"] = loss
        if bandwidth is not None:
            changes["bandwidth_bps"] = bandwidth
        if outage:
            changes["outages"] = tuple(parse_outage(o) for o in outage)
        up = dataclasses.replace(up, **changes)
        down = dataclasses.replace(down, **changes)
        vehicle_fields: dict[str, Any] = {
            "telemetry_period_s": 1.0 / telemetry_rate_hz,
            "los_policy": los_policy,  # VehicleConfig checks it
            "los_hold_after_s": los_hold_after,
            "faults": tuple(parse_fault(f) for f in fault or ()),
            "safing": not no_safing,
        }
        if truth_log is not None and not truth_log.parent.is_dir():
            raise ValueError(f"--truth-log {truth_log}: no directory {truth_log.parent}")
        if robot is not None:
            vehicle = vehicle_config_for(
                _load(robot),
                acs_overrides=None if acs_config is None else _acs_table(acs_config),
                **vehicle_fields,
            )
        else:
            if acs_config is not None:
                from planner.description import load_acs_config
                from planner.dynamics import DynamicsWorkspace
                from planner.model import default_model

                vehicle_fields["acs_gains"] = load_acs_config(
                    DynamicsWorkspace(default_model()), acs_config
                )
            vehicle = VehicleConfig(**vehicle_fields)
        if vehicle_config is not None:
            vehicle = _with_vehicle_tables(vehicle, vehicle_config)
        contact = None
        if mission is not None:
            contact = _contact(mission, mission_start, windows, relay or (), hours)
        elif any(o is not None for o in (mission_start, windows, relay, fast_scale)):
            raise ValueError("--mission-start, --windows, --relay and --fast-scale need --mission")
        config = ProcessConfig(
            ground_url=ground[0],
            standby_urls=tuple(ground[1:]),
            token=token,
            time_scale=time_scale,
            vehicle=vehicle,
            uplink=up,
            downlink=down,
            seed=seed,
            truth_log=truth_log,
            garbage=tuple(parse_garbage(g) for g in garbage or ()),
            contact=contact,
            fast_scale=fast_scale,
        )
    except (ValueError, OSError) as exc:
        _fail(str(exc))

    async def main_async() -> None:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(sig, stop.set)
        process = SpacecraftProcess(config)
        await process.run(stop)
        err_console.print(
            f"spacecraft stopped: {process.store.unacked} frames unacknowledged, "
            f"{process.connections} connections"
            + (f", {process.garbage_sent} malformed messages sent" if garbage else "")
        )

    asyncio.run(main_async())


def _contact(
    mission: Path, start: str | None, windows: Path | None, relays: Sequence[str], hours: float
) -> Any:
    """The spacecraft's contact plan from its --mission options (ValueError: one line)."""
    from mission import MissionError, load_mission, parse_utc
    from spacecraft.contact import load_contact

    try:
        start_utc = load_mission(mission).orbit.epoch_utc if start is None else parse_utc(start)
    except MissionError as exc:
        raise ValueError(str(exc)) from None
    return load_contact(mission, start_utc, windows_path=windows, relays=relays, hours=hours)


def _spacecraft_token(token: str | None, token_file: Path | None) -> str:
    """The spacecraft's token: given, else read from ``token_file``; one error line when
    there is none (docs/operations.md "Settings")."""
    if token and token.strip():
        return token.strip()
    if token_file is not None:
        try:
            text = token_file.read_text().strip()
        except OSError as exc:
            _fail(f"--token-file {token_file}: {exc.strerror or exc}")
        if not text:
            _fail(f"--token-file {token_file} is empty")
        return text
    _fail(
        "no spacecraft token: give --token-file FILE or set HIKOBOSHI_SPACECRAFT_TOKEN "
        "(or HIKOBOSHI_SPACECRAFT_TOKEN_FILE)"
    )


def _with_vehicle_tables(vehicle: Any, path: Path) -> Any:
    """``vehicle`` (a VehicleConfig) with the servos and sensor noise of ``path``'s
    ``[servo]`` and ``[sensor_noise]`` tables (planner.description.load_vehicle_tables)."""
    import dataclasses

    from planner.description import load_vehicle_tables, servo_gains_of
    from spacecraft.vehicle_config import SensorNoise

    tables = load_vehicle_tables(path, vehicle.model.n_joints)
    if tables.servo is not None:
        sim = dataclasses.replace(vehicle.sim, servo=servo_gains_of(tables.servo, vehicle.model))
        vehicle = dataclasses.replace(vehicle, sim=sim)
    if tables.sensor_noise is not None:
        noise = SensorNoise(**dataclasses.asdict(tables.sensor_noise))
        vehicle = dataclasses.replace(vehicle, noise=noise)
    return vehicle


def _acs_table(path: Path) -> dict[str, object]:
    """The ``[acs]`` table of an attitude-control TOML file (``--acs-config``)."""
    import tomllib

    try:
        with path.open("rb") as f:
            doc = tomllib.load(f)
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise ValueError(f"{path}: cannot read the attitude-control configuration: {exc}") from None
    if set(doc) != {"acs"} or not isinstance(doc["acs"], dict):
        raise ValueError(f"{path}: expected one [acs] table (found {sorted(doc)})")
    return dict(doc["acs"])


def _is_loopback(host: str) -> bool:
    import ipaddress

    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


@app.command()
def serve(
    host: Annotated[str, typer.Option(help="Address to listen on")] = "127.0.0.1",
    port: Annotated[int, typer.Option(help="Port to listen on")] = 8000,
    robot: Annotated[
        list[Path] | None,
        typer.Option(
            "--robot",
            help="A robot description (TOML) the server may plan for, besides those shipped "
            "under examples/robots/; plan requests name it by its name. Repeatable.",
        ),
    ] = None,
    log_format: LogFormatOption = "text",
    log_level: LogLevelOption = "info",
    foxglove_port: FoxglovePortOption = None,
) -> None:
    """Run the ground service. Settings from the environment: DATABASE_URL (default SQLite
    under HIKOBOSHI_DATA_DIR, ./data), HIKOBOSHI_TOKENS (token=name:role,...; required
    unless listening on loopback only), HIKOBOSHI_ROBOTS (description files, as --robot),
    HIKOBOSHI_TRUSTED_PROXIES (the reverse proxy's addresses or networks, comma-separated:
    X-Forwarded-For is believed from them only; none by default). The HTTP edge's limits
    and timeouts are in docs/security.md."""
    from server.api.edge import uvicorn_config
    from server.app import GroundServer, create_app
    from server.redaction import install_redaction
    from server.settings import Settings

    install_redaction()  # before anything logs (uvicorn_config installs it too)
    _configure_logging(log_format, log_level)
    startup_log = logging.getLogger("hikoboshi.ground.settings")

    try:
        settings = Settings.from_env()
    except ValueError as exc:
        _fail(f"bad settings in the environment: {exc}")
    if robot:
        settings = settings.model_copy(
            update={"robot_files": (*settings.robot_files, *(p.resolve() for p in robot))}
        )
    if foxglove_port is not None:
        settings = settings.model_copy(update={"foxglove_port": foxglove_port})
    if settings.foxglove_port is not None:
        _check_foxglove(settings.foxglove_port)
    for path in settings.robot_files:
        _load(path)  # one clear error line for a bad description, before serving
    if not settings.tokens:
        if not _is_loopback(host):
            _fail(
                f"HIKOBOSHI_TOKENS is empty and --host {host} is not loopback: refusing to "
                "serve a network with no tokens. Set HIKOBOSHI_TOKENS=token=name:role,... "
                '(strong tokens: python -c "import secrets; print(secrets.token_urlsafe(32))")'
            )
        # through the log (its format: a JSON collector reads every line), not a bare print
        startup_log.warning("HIKOBOSHI_TOKENS is empty: every API call will be refused")
    weak = sorted({t.name for secret, t in settings.tokens.items() if len(secret) < 16})
    if weak:
        startup_log.warning(
            "short (guessable) tokens for %s",
            ", ".join(weak),
            extra={"fields": {"event": "weak_tokens", "names": weak}},
        )
    ground = create_app(settings)
    config = uvicorn_config(ground, settings, host=host, port=port, log_level=log_level.lower())
    # On SIGTERM it stops the worker pool first: requests waiting answer JSON 503
    # shutting_down and no job process outlives it (docs/operations.md "Stopping").
    GroundServer(config, ground).run()


@app.command()
def calibrate(
    out: Annotated[
        Path, typer.Option(help="The [acs] TOML file to write (--acs-config reads it).")
    ],
    mcap: Annotated[
        Path | None, typer.Option(help="Fit to this recorded pass (.mcap) instead of the paper.")
    ] = None,
    pass_id: Annotated[
        str | None,
        typer.Option(
            "--pass",
            help="Fit to this stored pass (DATABASE_URL, else SQLite under HIKOBOSHI_DATA_DIR).",
        ),
    ] = None,
    parameters: Annotated[
        str,
        typer.Option(
            help="Comma-separated law parameters to fit among bandwidth_radps, damping_ratio, "
            "rate_filter_tau_s, integral_time_s, torque_limit_nm, dead_band_deg"
        ),
    ] = "bandwidth_radps,damping_ratio",
    max_evaluations: Annotated[
        int, typer.Option(help="Budget of model evaluations (about 2 s each for the paper).")
    ] = 40,
    vehicle_check: Annotated[
        bool,
        typer.Option(
            help="Paper fit: also fly the start and the fit through the vehicle (about 30 s)."
        ),
    ] = True,
    report: Annotated[Path | None, typer.Option(help="Where to write the JSON report.")] = None,
    servo: Annotated[
        bool,
        typer.Option(
            help="With a recorded pass: also fit the joint servos (lag, and bandwidth where "
            "observable) and estimate the sensor noise, with their report rows."
        ),
    ] = True,
    servo_max_evaluations: Annotated[
        int,
        typer.Option(help="Optimiser steps for the servos (each a few simulations of the arm)."),
    ] = 20,
    vehicle_out: Annotated[
        Path | None,
        typer.Option(
            help="With a recorded pass: write the fitted servo and sensor_noise tables here "
            "(a robot description's keys; hikoboshi spacecraft --vehicle-config reads it)."
        ),
    ] = None,
    as_json: Annotated[
        bool,
        typer.Option(
            "--json", help="Print one JSON object: the report's fields and the files written."
        ),
    ] = False,
) -> None:
    """Fit the attitude-control law's parameters (SciPy least squares) to the paper's targets
    or to a recorded pass; write the [acs] configuration and a report of every target. From
    a recorded pass also the joint servos and the sensor noise (--vehicle-out)."""
    from planner.errors import InvalidInput
    from spacecraft.calibration import write_acs_config
    from spacecraft.calibration_paper import fit_to_paper
    from spacecraft.calibration_recording import fit_to_recording
    from spacecraft.servo_fit import write_vehicle_config

    if mcap is not None and pass_id is not None:
        _fail("give --mcap or --pass, not both")
    if vehicle_out is not None and ((mcap is None and pass_id is None) or not servo):
        _fail("--vehicle-out needs a recorded pass (--mcap or --pass) and --servo")
    if servo_max_evaluations < 1:
        _fail(f"--servo-max-evaluations {servo_max_evaluations} must be >= 1")
    if max_evaluations < 1:
        _fail(f"--max-evaluations {max_evaluations} must be >= 1")
    names = tuple(p.strip() for p in parameters.split(",") if p.strip())
    recording = None
    if mcap is not None or pass_id is not None:
        import io

        from telemetry.mcap import RecordingFileError, read_mcap

        try:
            if mcap is not None:
                recording = read_mcap(mcap)
            elif pass_id is not None:
                from hikoboshi.post_cli import _session
                from server.services.recordings import recording_mcap

                with _session() as session:
                    _, data = recording_mcap(session=session, pass_id=pass_id)
                recording = read_mcap(io.BytesIO(data))
        except (RecordingFileError, OSError) as exc:
            _fail(f"{mcap or pass_id}: {exc}")
    with Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        TextColumn("{task.completed:.0f}/{task.total:.0f}"),
        TextColumn("cost {task.fields[cost]}"),
        TimeRemainingColumn(),
        console=err_console,
    ) as progress:
        task = progress.add_task("calibrating", total=max_evaluations, cost="-")

        def on_progress(done: int, total: int, cost: float) -> None:
            progress.update(task, completed=done, total=total, cost=f"{cost:.4g}")

        servo_task = None

        def on_servo(done: int) -> None:
            # The arm's simulations: at most one for the start, then per optimiser step one
            # and two per fitted parameter (a lag and a bandwidth per joint).
            nonlocal servo_task
            if servo_task is None:
                assert recording is not None
                joints = int(recording.plan.command_joints_rad.shape[1])
                most = 1 + servo_max_evaluations * (1 + 4 * joints)
                servo_task = progress.add_task("servos", total=most, cost="-")
            progress.update(servo_task, completed=done)

        try:
            if recording is not None:
                result = fit_to_recording(
                    recording,
                    names,
                    max_evaluations=max_evaluations,
                    progress=on_progress,
                    servo_and_noise=servo,
                    servo_max_evaluations=servo_max_evaluations,
                    servo_progress=on_servo,
                )
                if servo_task is not None:
                    progress.update(servo_task, completed=progress.tasks[servo_task].total)
            else:
                result = fit_to_paper(
                    names,
                    max_evaluations=max_evaluations,
                    progress=on_progress,
                    check_vehicle=vehicle_check,
                )
        except InvalidInput as exc:
            _fail(str(exc))
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        write_acs_config(out, result.parameters)
        if report is not None:
            report.parent.mkdir(parents=True, exist_ok=True)
            report.write_text(json.dumps(result.to_dict(), indent=2) + "\n")
        if vehicle_out is not None:
            vehicle_out.parent.mkdir(parents=True, exist_ok=True)
            write_vehicle_config(vehicle_out, result.servo, result.sensor_noise)
    except OSError as exc:
        _fail(str(exc))
    if as_json:
        written = [str(p) for p in (out, report, vehicle_out) if p is not None]
        sys.stdout.write(json.dumps({**result.to_dict(), "wrote": written}) + "\n")
        return
    _print_calibration(result)
    console.print(f"wrote {out}" + ("" if report is None else f" and {report}"), highlight=False)
    if vehicle_out is not None:
        console.print(f"wrote {vehicle_out}", highlight=False)


def _print_calibration(result: Any) -> None:
    def num(value: float | None) -> str:
        return "-" if value is None else f"{value:.4g}"

    def holds(value: bool | None) -> str:
        return "not checked" if value is None else ("holds" if value else "does not hold")

    params = Table(title=f"fit ({result.kind}): {result.message}")
    for column in ("parameter", "start", "fit", "standard error"):
        params.add_column(column)
    for name, value in result.parameters.items():
        se = None if result.standard_error is None else result.standard_error.get(name)
        params.add_row(name, num(result.start[name]), num(value), num(se))
    console.print(params)
    table = Table(title=f"targets (cost {result.cost_start:.4g} -> {result.cost:.4g})")
    for column in ("target", "tolerance", "source", "start", "fit", "at start", "at fit"):
        table.add_column(column)
    for row in result.targets:
        table.add_row(
            row.target + (f" ({row.note})" if row.note else ""),
            row.tolerance,
            row.source,
            num(row.start),
            num(row.fit),
            holds(row.holds_start),
            holds(row.holds),
        )
    console.print(table)


def main() -> None:
    app()
