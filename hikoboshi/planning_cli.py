"""``hikoboshi plan``: an experiment's parameters from the command line to a plan file
checked against the flight rules (exit 3 when it fails one), ``plan check FILE`` for a
stored plan, ``plan upload FILE`` to store it on a ground service, and ``plan campaign``
(:mod:`hikoboshi.campaign_cli`). Planning and checking are the ground's own
(:mod:`server.operations.planning`): the command line computes nothing of its own.

The planner (SciPy, MuJoCo: most of a second) is imported when a plan is made or the
command's own help is shown, not when the command line starts: ``hikoboshi --help`` and
every other command start without it (tests/test_cli_startup.py)."""

from __future__ import annotations

import contextlib
import inspect
import json
import os
import sys
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.markup import escape
from rich.table import Table
from typer.core import TyperCommand

from hikoboshi.cli_common import RobotOption, _fail, _load, console, err_console

if TYPE_CHECKING:
    pass

__all__ = ["register", "write_atomically"]


def write_atomically(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` so that a reader sees the old file or the whole new one."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


#: The first paragraph of ``plan``'s help: what ``hikoboshi --help`` lists it with.
_PLAN_SUMMARY = (
    "Plan an experiment (ptp, reactionless, gjm, coordination, nonholonomic, pass) as a "
    "4 Hz time-tagged command plan with its prediction, and write it as JSON; or a "
    "campaign of passes over a mission's windows (plan campaign --mission FILE --start "
    "ISO8601; docs/missions.md). Parameters "
    "are set with --set NAME=VALUE (tuples comma-separated); the defaults reproduce the "
    "paper's experiment. With --robot FILE the plan is for that robot: its poses, and "
    "its [experiments.NAME] tables as the defaults. plan check FILE checks a plan file; "
    "plan upload FILE stores it on a ground service (--url, --token), which checks it again "
    "and flies exactly its commands."
)


def _plan_help() -> str:
    from server.operations.planning import parameters_help

    return _PLAN_SUMMARY + "\n\nParameters:\n\n" + parameters_help()


class _PlanCommand(TyperCommand):
    """``plan``, whose help (its summary, then every experiment's parameters, which only
    the planner knows) is made when it is read: by ``plan --help``, not at start-up.
    ``hikoboshi --help`` lists the command by its summary (``short_help``)."""

    @property
    def help(self) -> str:
        return inspect.cleandoc(_plan_help())

    @help.setter
    def help(self, _value: str | None) -> None:
        """Typer sets the function's docstring; the help is the property's."""


def plan_command(
    experiment: Annotated[
        str,
        typer.Argument(
            help="ptp, reactionless, gjm, coordination, nonholonomic or pass; or check, to "
            "evaluate a plan FILE against the flight rules; or upload, to store a plan FILE "
            "on a ground service"
        ),
    ],
    file: Annotated[Path | None, typer.Argument(help="check, upload: the plan JSON file.")] = None,
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
        Path | None,
        typer.Option(
            "--mission",
            help="campaign: the mission file (TOML), or a shipped mission's name (ets7-1999).",
        ),
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
    url: Annotated[
        str,
        typer.Option("--url", envvar="HIKOBOSHI_URL", help="upload: the ground service's address."),
    ] = "http://127.0.0.1:8000",
    token: Annotated[
        str | None,
        typer.Option(
            "--token",
            envvar="HIKOBOSHI_TOKEN",
            help="upload: an operator's API token (better given as HIKOBOSHI_TOKEN).",
            show_default=False,
        ),
    ] = None,
) -> None:
    """Plan (exit 3 when the plan fails a flight rule: the file is still written, with its
    rules table, so that it can be looked at), or ``plan check FILE``, or ``plan upload
    FILE`` (through the ground service's REST API, as any client: the ground checks the
    plan again and prints the stored plan's id; exit 3 when its check fails), or ``plan
    campaign --mission FILE --start ISO8601 [--out DIR]``: one plan per pass over
    consecutive windows and a campaign.json (docs/missions.md)."""
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
    if experiment in ("check", "upload"):
        if file is None:
            _fail(f"plan {experiment} needs the plan FILE")
        if experiment == "upload":
            _plan_upload(file, url, token, as_json=as_json)
        else:
            _plan_check(file, robot, as_json=as_json)
        return
    if file is not None:
        _fail(f"unexpected argument {str(file)!r} (only plan check and upload take a FILE)")
    if out is None:
        _fail("give --out FILE: where to write the plan")
    from planner.errors import PlannerError
    from server.operations.planning import experiment_parameters, plan_checked
    from server.services.errors import DomainError

    description = _load(robot) if robot is not None else None
    try:
        status = (
            contextlib.nullcontext()
            if as_json
            else console.status(f"planning {experiment}, then the flight rules", spinner="dots")
        )
        with status:
            params = experiment_parameters(experiment, description, assignments=assignments or [])
            checked = plan_checked(
                experiment, params, robot=description, optimise_offset=optimise_offset_flag
            )
    except (PlannerError, DomainError) as exc:
        _fail(str(exc))
    plan, report = checked.plan, checked.report
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
    from server.operations.planning import check
    from server.services.errors import DomainError

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
            report = check(plan, description).report
    except (PlannerError, DomainError) as exc:
        _fail(str(exc))
    if as_json:
        sys.stdout.write(json.dumps({"plan": str(file), **_rules_summary(report)}) + "\n")
    else:
        console.print(
            f"{file}: {plan.experiment} for {plan.robot}, {plan.duration_s:.2f} s", highlight=False
        )
        _print_rules(report)
    _exit_on_rules(report, quiet=as_json)


def _plan_upload(file: Path, url: str, token: str | None, *, as_json: bool) -> None:
    """POST the file to ``/api/plans/documents`` as it is; the stored plan's id and the
    ground's verdict (exit 3 when its check fails: stored, but a pass of it will not start)."""
    from hikoboshi.demo_harness import DemoError, _Api
    from planner.flight_rules import FlightRulesReport

    if not token:
        _fail("plan upload needs an operator's token: HIKOBOSHI_TOKEN or --token")
    try:
        data = file.read_bytes()
    except OSError as exc:
        _fail(f"{file}: {exc.strerror}")
    api = _Api(url.rstrip("/"), token, logs=f"is the ground service at {url} running?")
    try:
        status = (
            contextlib.nullcontext()
            if as_json
            else console.status(f"the ground checks {file.name}", spinner="dots")
        )
        with status:
            stored = api.call("POST", "/api/plans/documents", data=data, timeout_s=900.0)
    except DemoError as exc:
        _fail(str(exc))
    report = FlightRulesReport.from_dict(stored["flight_rules"])
    if as_json:
        sys.stdout.write(json.dumps(stored) + "\n")
    else:
        console.print(
            f"stored plan {stored['id']}: {stored['experiment']}, {stored['n_commands']} "
            f"commands, {stored['duration_s']:.2f} s; the ground's flight rules: "
            + ("pass" if report.passed else "FAIL (a pass of it will not start)"),
            highlight=False,
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


def register(app: typer.Typer) -> None:
    """Add ``plan`` (an experiment, ``check``, ``upload`` and ``campaign``) to
    ``hikoboshi``."""
    app.command("plan", cls=_PlanCommand, short_help=_PLAN_SUMMARY)(plan_command)
