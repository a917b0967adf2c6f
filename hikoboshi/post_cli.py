"""Post-pass commands: ``hikoboshi report`` and ``hikoboshi mcap export|import``.

A PASS is a pass id in the configured database (``DATABASE_URL``, else SQLite under
``HIKOBOSHI_DATA_DIR``, as for ``hikoboshi serve``; migrated to the current schema first) or,
for ``report``, the path of an ``.mcap`` recording. Failures print one line on stderr and
exit with status 2.
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, NoReturn

import typer

from hikoboshi.output import HELP_MARKUP, make_console

if TYPE_CHECKING:
    from sqlalchemy.orm import Session

    from server.schemas import ReportPublic

__all__ = ["mcap_app", "register"]

#: Who the audit log names for what the command line does.
ACTOR = "hikoboshi-cli"

mcap_app = typer.Typer(
    rich_markup_mode=HELP_MARKUP,
    no_args_is_help=True,
    help="Pass recordings as MCAP: export, import.",
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
def _session() -> Iterator[Session]:
    """A session on the configured database, migrated to head; errors become one line."""
    from server.services.errors import DomainError
    from server.settings import Settings
    from server.storage.db import make_engine, session_factory, upgrade
    from server.storage.errors import StorageError

    try:
        settings = Settings.from_env()
        engine = make_engine(settings.resolved_database_url())
    except ValueError as exc:
        _fail(f"bad settings in the environment: {exc}")
    try:
        upgrade(engine)
        with session_factory(engine)() as session:
            yield session
    except DomainError as exc:
        _fail(exc.message)
    except StorageError as exc:
        _fail(str(exc))
    finally:
        engine.dispose()


def _is_file(target: str) -> bool:
    return target.endswith(".mcap") or Path(target).is_file()


def _write_report(out: Path, report: ReportPublic, figures: dict[str, bytes]) -> None:
    from server.services.reports import render_html

    out.mkdir(parents=True, exist_ok=True)
    (out / "report.json").write_text(report.model_dump_json(indent=2) + "\n")
    (out / "report.html").write_text(render_html(report, {n: f"{n}.png" for n in figures}))
    for name, png in figures.items():
        (out / f"{name}.png").write_bytes(png)


def _report_from_file(path: Path) -> tuple[ReportPublic, dict[str, bytes]]:
    from server.services.analyses import compute_analyses
    from server.services.reports import build_report
    from telemetry.mcap import RecordingFileError, read_mcap

    try:
        recording = read_mcap(path)
    except (RecordingFileError, OSError) as exc:
        _fail(f"{path}: {exc}")
    run = compute_analyses(recording)
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
) -> None:
    """Write a pass report: report.json (the numbers in tables), report.html and the
    figures. A stored pass's newest analyses are used (run and stored first if it has none,
    or with --recompute); an .mcap file is analysed on the spot."""
    if _is_file(target):
        found = _report_from_file(Path(target))
    else:
        from server.services import analyses
        from server.services.reports import stored_report

        with _session() as session:
            if recompute or not analyses.newest_documents(session=session, pass_id=target):
                err_console.print(f"analysing pass {target} ...")
                analyses.run_analyses(session=session, pass_id=target, actor=ACTOR)
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


def register(app: typer.Typer) -> None:
    """Add ``report`` and ``mcap`` to the main command line."""
    app.command("report")(report)
    app.add_typer(mcap_app, name="mcap")
