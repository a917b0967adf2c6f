"""``hikoboshi demo`` (the ground service, the simulated spacecraft and a whole pass:
:mod:`hikoboshi.demo`; with ``--campaign`` a mission's passes: :mod:`hikoboshi.campaign_demo`)
and ``hikoboshi ptp-demo`` (one PTP motion on the free-floating model:
:mod:`server.operations.foundation_demo`): their options, progress bars and printed summaries."""

from __future__ import annotations

import contextlib
import json
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Annotated, Any

import typer
from rich import box
from rich.markup import escape
from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn
from rich.table import Table

from hikoboshi.cli_common import (
    FoxglovePortOption,
    LogFormatOption,
    LogLevelOption,
    RobotOption,
    _check_foxglove,
    _configure_logging,
    _fail,
    _load,
    console,
    err_console,
)

__all__ = ["register"]


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
    reports: Annotated[
        bool,
        typer.Option(
            "--reports/--no-reports",
            help="Run the post-pass analyses and write the report and the MCAP recording "
            "(--no-reports: the summary alone, sooner).",
        ),
    ] = True,
    as_json: Annotated[bool, typer.Option("--json", help="Print only the JSON summary.")] = False,
    robot: RobotOption = None,
    fault: Annotated[
        list[str] | None,
        typer.Option(
            help="A fault for the spacecraft, NAME@T[,key=value...], T in onboard s from the "
            "spacecraft's start (as --outage), or NAME@cmd+T, T after the first command "
            "executed: jointN-stuck, jointN-drift[,rate_degps=], jointN-offset[,deg=], "
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
        if outage or fault or robot is not None or experiments or serve_after or not reports:
            _fail(
                "--campaign takes its windows and experiments from the mission: no --outage, "
                "--fault, --robot, --experiments, --serve-after or --no-reports"
            )
        _campaign_demo(mission, start, out, speed, loss, port, seed, as_json, log_format, log_level)
        return
    chosen = tuple(e.strip() for e in experiments.split(",") if e.strip()) if experiments else ()
    if robot is not None:
        _load(robot)  # a bad description: one error line before anything starts
    from hikoboshi.demo import DemoOptions, check_fault_specs, run_demo
    from hikoboshi.demo_harness import DemoError

    try:
        check_fault_specs(fault or (), robot)
    except DemoError as exc:
        _fail(str(exc))
    shown: list[dict[str, Any]] = []

    def show(summary: dict[str, Any]) -> None:
        """The summary and its verdict, once: when the pass is over (before --serve-after's
        serving), or at the end."""
        if shown:
            return
        shown.append(summary)
        if as_json:
            sys.stdout.write(json.dumps(summary) + "\n")
            sys.stdout.flush()
        else:
            _print_demo(summary)

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
        reports=reports,
        on_ready=None if as_json else _announce,
        log_format=log_format,
        log_level=log_level.lower(),
        foxglove_port=foxglove_port,
        on_summary=show,
    )
    out.mkdir(parents=True, exist_ok=True)
    if foxglove_port is not None and not as_json:
        console.print(
            f"Foxglove live view: ws://127.0.0.1:{foxglove_port}/?token=TOKEN (a viewer's "
            f"token of {out / 'tokens'})"
        )
    ground_log = (out / "ground.log").open("a", encoding="utf-8")  # open until the exit
    _configure_logging(log_format, log_level, stream=ground_log)
    with _phase_bars(as_json, {"pass": "pass (onboard s)"}) as on_progress:
        try:
            summary = run_demo(options, on_progress)
        except DemoError as exc:
            _fail(f"demo stopped: {exc} (logs in {out})")
    show(summary)
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
    from hikoboshi.campaign_demo import run_campaign_demo
    from hikoboshi.campaign_passes import CampaignOptions
    from hikoboshi.campaign_report import campaign_markdown
    from hikoboshi.demo_harness import DemoError
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
    if summary["report_html"] is not None:  # None with --no-reports
        console.print(f"Report: {summary['report_html']} (and report.json)")
        console.print(f"Recording (MCAP, opens in Foxglove): {summary['recording_mcap']}")
    if summary["analyses_failed"]:
        console.print(f"Analyses that failed (see the report): {summary['analyses_failed']}")
    folder = summary["database"].rsplit("/", 1)[0]
    console.print(f"Summary: {folder}/summary.json")
    console.print(f"Database: {summary['database']}")
    console.print(  # what the post-pass commands take: the pass id and the data folder
        f"Pass id: {summary['pass_id']} (HIKOBOSHI_DATA_DIR={folder} hikoboshi report "
        f"{summary['pass_id']} --out report)",
        highlight=False,
        soft_wrap=True,
    )
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


def ptp_demo(
    out: Annotated[Path, typer.Option(help="Where to write the results.")] = Path("out/ptp-demo"),
    as_json: Annotated[bool, typer.Option("--json", help="Print only the JSON summary.")] = False,
) -> None:
    """Simulate PTP A->B on the free-floating model (no ground, no link) and report the
    base's attitude response against the eq. (10) prediction."""
    from server.operations import foundation_demo

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


def register(app: typer.Typer) -> None:
    """Add ``demo`` and ``ptp-demo`` to ``hikoboshi``."""
    app.command("demo")(demo)
    app.command("ptp-demo")(ptp_demo)
