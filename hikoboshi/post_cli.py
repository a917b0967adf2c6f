"""Post-pass commands: ``hikoboshi report``, ``hikoboshi mcap export|import`` and
``hikoboshi export telemetry|quantity``.

A PASS is a pass id in the configured database (``DATABASE_URL``, else SQLite under
``HIKOBOSHI_DATA_DIR``, as for ``hikoboshi serve``; migrated to the current schema first) or,
for ``report``, the path of an ``.mcap`` recording. Failures print one line on stderr and
exit with status 2.
"""

from __future__ import annotations

import json
import shutil
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, NoReturn

import typer

from hikoboshi.output import HELP_MARKUP, make_console

if TYPE_CHECKING:
    from sqlalchemy.orm import Session, sessionmaker

    from server.schemas.analyses import ReportPublic

__all__ = ["export_app", "mcap_app", "register"]

#: Who the audit log names for what the command line does.
ACTOR = "hikoboshi-cli"

mcap_app = typer.Typer(
    rich_markup_mode=HELP_MARKUP,
    no_args_is_help=True,
    help="Pass recordings as MCAP: export, import.",
)
export_app = typer.Typer(
    rich_markup_mode=HELP_MARKUP,
    no_args_is_help=True,
    help="Data out of the database: a pass's telemetry as CSV or Parquet, one quantity "
    "across passes.",
)
console = make_console()
err_console = make_console(stderr=True)


def _fail(reason: str) -> NoReturn:
    err_console.print(f"error: {reason}", markup=False, highlight=False, soft_wrap=True)
    raise typer.Exit(code=2)


def _print_json(doc: dict[str, Any]) -> None:
    """One JSON object on one line of stdout (--json)."""
    sys.stdout.write(json.dumps(doc) + "\n")


@contextmanager
def _sessions() -> Iterator[sessionmaker[Session]]:
    """Sessions on the configured database, migrated to head; errors become one line."""
    from server.services.errors import DomainError
    from server.settings import Settings
    from server.storage.db import make_engine, session_factory, upgrade
    from server.storage.errors import NotFound, StorageError

    try:
        settings = Settings.from_env()
        engine = make_engine(settings.resolved_database_url())
    except ValueError as exc:
        _fail(f"bad settings in the environment: {exc}")
    try:
        upgrade(engine)
        yield session_factory(engine)
    except DomainError as exc:
        _fail(exc.message)
    except NotFound as exc:  # which database was read, and how to read another
        where = engine.url.render_as_string(hide_password=True)
        _fail(
            f"{exc} in the database {where} (HIKOBOSHI_DATA_DIR or DATABASE_URL name "
            "another: the demo's is its --out folder, HIKOBOSHI_DATA_DIR=out/demo)"
        )
    except StorageError as exc:
        _fail(str(exc))
    finally:
        engine.dispose()


@contextmanager
def _session() -> Iterator[Session]:
    """A session on the configured database, migrated to head; errors become one line."""
    with _sessions() as sessions, sessions() as session:
        yield session


def _is_file(target: str) -> bool:
    return target.endswith(".mcap") or Path(target).is_file()


def _write_report(out: Path, report: ReportPublic, figures: dict[str, bytes]) -> None:
    from server.services.reports import render_html

    out.mkdir(parents=True, exist_ok=True)
    (out / "report.json").write_text(report.model_dump_json(indent=2) + "\n")
    (out / "report.html").write_text(render_html(report, {n: f"{n}.png" for n in figures}))
    for name, png in figures.items():
        (out / f"{name}.png").write_bytes(png)


def _robot_files(robot: list[Path] | None) -> tuple[str, ...]:
    """The descriptions a report may need (its plan's robot, found by hash): ``--robot``
    and ``HIKOBOSHI_ROBOTS``, as ``hikoboshi serve`` knows them."""
    from server.settings import Settings

    try:
        configured = Settings.from_env().robot_files
    except ValueError as exc:
        _fail(f"bad settings in the environment: {exc}")
    return tuple(str(p.resolve()) for p in (*configured, *(robot or ())))


def _robot_unknown(exc: Exception) -> NoReturn:
    message = getattr(exc, "message", str(exc)).split(": start it with")[0]
    _fail(f"{message}: name its description with --robot FILE")


def _report_from_file(
    path: Path, robot_files: tuple[str, ...]
) -> tuple[ReportPublic, dict[str, bytes]]:
    from server.services.analyses import compute_analyses
    from server.services.errors import ConflictError
    from server.services.report_tables import predicted_of
    from server.services.reports import build_report
    from server.services.robots import model_for_plan
    from telemetry.mcap import RecordingFileError, read_mcap

    try:
        recording = read_mcap(path)
    except (RecordingFileError, OSError) as exc:
        _fail(f"{path}: {exc}")
    try:
        # the plan's own robot: another robot's frames analysed with ETS-VII's model fail
        # on their shapes, or worse, give numbers of the wrong arm
        model = model_for_plan(recording.plan, robot_files)
    except ConflictError as exc:
        _robot_unknown(exc)
    run = compute_analyses(recording, model, robot_files)
    now_ns = time.time_ns()
    state = recording.meta.get("state")
    report = build_report(
        pass_id=None,
        name=recording.name,
        state=state if isinstance(state, str) else None,
        experiment=recording.plan.experiment,
        imported=False,
        documents={kind: (doc, now_ns) for kind, doc in run.documents.items()},
        figure_names=list(run.figures),
        alarms=recording.alarms,
        epoch_ns=recording.epoch_ns,
        plan=predicted_of(
            {
                "robot": recording.plan.robot,
                "robot_hash": recording.plan.robot_hash,
                "experiment": recording.plan.experiment,
                "metrics": recording.plan.metrics,
            }
        ),
    )
    return report, run.figures


def report(
    target: Annotated[str, typer.Argument(metavar="PASS", help="Pass id, or an .mcap file.")],
    out: Annotated[Path, typer.Option(help="Directory for report.json, report.html, PNGs.")],
    recompute: Annotated[
        bool, typer.Option(help="Analyse the stored pass again even if it has results.")
    ] = False,
    as_json: Annotated[
        bool,
        typer.Option("--json", help="Print one JSON object: what was written, each analysis."),
    ] = False,
    robot: Annotated[
        list[Path] | None,
        typer.Option(
            help="The description of the pass's robot when it is not a shipped one (found by "
            "its hash, as hikoboshi serve --robot; also HIKOBOSHI_ROBOTS). Repeatable."
        ),
    ] = None,
) -> None:
    """Write a pass report: report.json (the numbers in tables), report.html and the
    figures. A stored pass's newest analyses are used (run and stored first if it has none,
    or with --recompute); an .mcap file is analysed on the spot. Either is analysed with
    its plan's robot's model (ETS-VII's, a shipped robot's, or one given by --robot)."""
    robot_files = _robot_files(robot)
    if _is_file(target):
        found = _report_from_file(Path(target), robot_files)
    else:
        from server.services import analyses
        from server.services.errors import ConflictError
        from server.services.reports import stored_report

        with _session() as session:
            if recompute or not analyses.newest_documents(session=session, pass_id=target):
                err_console.print(f"analysing pass {target} ...")
                try:
                    analyses.run_analyses(
                        session=session, pass_id=target, actor=ACTOR, robot_files=robot_files
                    )
                except ConflictError as exc:
                    if exc.code != "robot_unknown":
                        raise
                    _robot_unknown(exc)
            found = stored_report(session, target)
    report_doc, figures = found
    _write_report(out, report_doc, figures)
    if as_json:
        _print_json(
            {
                "pass_id": report_doc.pass_id,
                "report_html": str(out / "report.html"),
                "report_json": str(out / "report.json"),
                "figures": [str(out / f"{name}.png") for name in figures],
                "analyses": [
                    {"kind": a.kind, "status": a.status, "error": a.error}
                    for a in report_doc.analyses
                ],
            }
        )
        return
    for status in report_doc.analyses:
        line = f"{status.kind}: {status.status}"
        console.print(line + (f" ({status.error})" if status.error else ""), highlight=False)
    console.print(f"wrote {out / 'report.html'}, report.json and {len(figures)} figures")


@mcap_app.command("export")
def mcap_export(
    target: Annotated[str, typer.Argument(metavar="PASS", help="Pass id in the database.")],
    out: Annotated[Path, typer.Option(help="The .mcap file to write.")],
    as_json: Annotated[
        bool, typer.Option("--json", help="Print one JSON object: the pass, file and size.")
    ] = False,
) -> None:
    """Write a stored pass as one MCAP file (docs/mcap.md)."""
    from server.services.recordings import recording_mcap

    with _session() as session:
        name, data = recording_mcap(session=session, pass_id=target)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_bytes(data)
    except OSError as exc:
        _fail(f"{out}: {exc}")
    if as_json:
        _print_json({"pass_id": target, "name": name, "path": str(out), "bytes": len(data)})
        return
    console.print(f"wrote pass {name!r} to {out} ({len(data)} bytes)", highlight=False)


@mcap_app.command("import")
def mcap_import(
    path: Annotated[Path, typer.Argument(metavar="FILE", help="An .mcap pass recording.")],
    as_json: Annotated[
        bool,
        typer.Option("--json", help="Print one JSON object: the id, name, state and counts."),
    ] = False,
) -> None:
    """Store an MCAP recording as a new, finished pass marked imported; prints its id (alone
    on stdout, for PASS=$(hikoboshi mcap import FILE)); what was stored goes to stderr."""
    from server.services.imports import import_mcap

    try:
        data = path.read_bytes()
    except OSError as exc:
        _fail(f"{path}: {exc}")
    with _session() as session:
        result = import_mcap(session, data, ACTOR, source=path.name)
    p = result.imported
    if as_json:
        _print_json(
            {
                "id": p.id,
                "name": p.name,
                "state": p.state,
                "frames": result.frames,
                "commands": result.commands,
                "events": result.events,
            }
        )
        return
    err_console.print(
        f"imported pass {p.id} ({p.name!r}, {p.state}): {result.frames} frames, "
        f"{result.commands} commands, {result.events} events",
        markup=False,
        highlight=False,
        soft_wrap=True,
    )
    sys.stdout.write(f"{p.id}\n")


@export_app.command("telemetry")
def export_telemetry(
    target: Annotated[str, typer.Argument(metavar="PASS", help="Pass id in the database.")],
    out: Annotated[
        Path, typer.Option(help="The file to write (.csv or .parquet); - for stdout (CSV).")
    ],
    format_: Annotated[
        str | None,
        typer.Option("--format", help="csv or parquet; default: from the --out suffix."),
    ] = None,
    as_json: Annotated[
        bool, typer.Option("--json", help="Print one JSON object: the file, format and rows.")
    ] = False,
) -> None:
    """Write every stored frame of a pass as CSV (units in the header) or Parquet (units in
    the schema metadata), as GET /api/passes/ID/telemetry.csv and .parquet do."""
    from server.services import exports

    to_stdout = str(out) == "-"
    chosen = format_ or ("csv" if to_stdout else out.suffix.removeprefix(".").lower())
    if chosen not in exports.FORMATS:
        _fail(
            f"--format {chosen!r} is not one of {sorted(exports.FORMATS)} (or give --out a "
            ".csv or .parquet suffix)"
        )
    if to_stdout and chosen != "csv":
        _fail("--out - writes CSV only: give a file for Parquet")
    rows = 0
    with _sessions() as sessions:
        with sessions() as session:
            export = exports.open_export(session, target)
        try:
            if to_stdout:
                stream = sys.stdout.buffer
                for chunk in exports.csv_chunks(sessions, export):
                    stream.write(chunk)
                stream.flush()
                return
            out.parent.mkdir(parents=True, exist_ok=True)
            with out.open("wb") as file:
                if chosen == "csv":
                    file.write(exports.csv_header(export))
                    for page in exports.pages(sessions, export):
                        file.write(exports.csv_rows(page))
                        rows += len(page)
                else:
                    spooled, _, rows = exports.parquet_file(sessions, export)
                    with spooled:
                        shutil.copyfileobj(spooled, file)
        except OSError as exc:
            _fail(f"{out}: {exc}")
    size = out.stat().st_size
    if as_json:
        _print_json(
            {
                "pass_id": export.pass_id,
                "path": str(out),
                "format": chosen,
                "rows": rows,
                "bytes": size,
            }
        )
        return
    console.print(
        f"wrote {rows} frames of pass {export.name!r} to {out} ({chosen}, {size} bytes)",
        markup=False,
        highlight=False,
    )


@export_app.command("quantity")
def export_quantity(
    field: Annotated[str, typer.Argument(help="One numeric telemetry field, e.g. hw1 or qz.")],
    passes: Annotated[
        list[str],
        typer.Option("--pass", help="A pass id in the database; repeatable (at most 20)."),
    ],
    buckets: Annotated[
        int, typer.Option(help="Equal spans of each pass's own duration.", min=1)
    ] = 200,
    out: Annotated[
        Path | None,
        typer.Option(help="Write the spans as CSV: pass_id, name, t_s, count, min, max, mean."),
    ] = None,
    plot: Annotated[
        Path | None, typer.Option(help="Plot the passes on one time axis (PNG).")
    ] = None,
    as_json: Annotated[
        bool, typer.Option("--json", help="Print the result as GET /api/telemetry/across does.")
    ] = False,
) -> None:
    """Compare one quantity across passes, each on its own time axis from its first frame,
    as GET /api/telemetry/across does: a table of each pass's frames, duration, min, max and
    mean, and optionally the spans as CSV and a plot."""
    from server.services import telemetry as service
    from telemetry.figures import quantity_across_figure

    with _session() as session:
        result = service.across_passes(
            session=session, field=field, pass_ids=passes, buckets=buckets
        )
    try:
        if out is not None:
            lines = ["pass_id,name,t_s,count,min,max,mean"]
            for p in result.passes:
                name = p.name.replace('"', '""')
                lines += [
                    f'{p.pass_id},"{name}",{b.t_s!r},{b.count},{b.min!r},{b.max!r},{b.mean!r}'
                    for b in p.buckets
                ]
            out.parent.mkdir(parents=True, exist_ok=True)
            out.write_text("\n".join(lines) + "\n", encoding="utf-8")
        if plot is not None:
            plot.parent.mkdir(parents=True, exist_ok=True)
            plot.write_bytes(
                quantity_across_figure(
                    result.field,
                    result.unit,
                    [
                        (
                            p.name,
                            [b.t_s for b in p.buckets],
                            [b.mean for b in p.buckets],
                            [b.min for b in p.buckets],
                            [b.max for b in p.buckets],
                        )
                        for p in result.passes
                        if p.buckets
                    ],
                )
            )
    except OSError as exc:
        _fail(str(exc))
    if as_json:
        _print_json(result.model_dump(mode="json"))
        return
    from rich.markup import escape
    from rich.table import Table

    unit = f" [{result.unit}]" if result.unit else ""
    table = Table(title=escape(f"{result.field}{unit} across {len(result.passes)} passes"))
    for column in ("pass", "name", "state", "frames", "duration s", "min", "max", "mean"):
        table.add_column(column, justify="left" if column in ("pass", "name", "state") else "right")
    for p in result.passes:
        shown = [f"{v:.6g}" if v is not None else "-" for v in (p.min, p.max, p.mean)]
        duration = f"{p.duration_s:.1f}" if p.duration_s is not None else "-"
        table.add_row(p.pass_id, escape(p.name), p.state, str(p.count), duration, *shown)
    console.print(table)


def register(app: typer.Typer) -> None:
    """Add ``report``, ``mcap`` and ``export`` to the main command line."""
    app.command("report")(report)
    app.add_typer(mcap_app, name="mcap")
    app.add_typer(export_app, name="export")
