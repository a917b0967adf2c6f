"""``hikoboshi calibrate``: the attitude-control law fitted to the paper's targets or to a
recorded pass (and, from a pass, the joint servos and the sensor noise;
:mod:`spacecraft.calibration`), written as the TOML the spacecraft reads, with a report of
every target."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn
from rich.table import Table

from hikoboshi.cli_common import _fail, console, err_console

__all__ = ["register"]


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


def register(app: typer.Typer) -> None:
    """Add ``calibrate`` to ``hikoboshi``."""
    app.command("calibrate")(calibrate)
