"""Pass reports: the newest stored analyses and the pass's alarms as tables, as JSON and as
one HTML page.

:func:`build_report` (its tables: :mod:`server.services.report_tables`) and
:func:`render_html` are pure (the command line uses them on a recording file, without a
database); :func:`pass_report` and :func:`pass_report_html` read the newest stored run of a
pass.

Figures in the served HTML are ``data:`` URIs, so the page is one self-contained document:
a browser ``<img>`` cannot send the ``Authorization`` header the API needs, and a page the
console fetches with its token and shows from a blob (or saves) has nothing left to fetch.
The alternative, short-lived signed figure URLs, would put a credential in URLs (history,
logs, Referer) and need a signing key the service does not otherwise have. The cost is
about 0.8 MB of base64 for the demo pass's six figures, in a page fetched on demand.
"""

from __future__ import annotations

import base64
import html
import json
from collections.abc import Mapping

from sqlalchemy.orm import Session

from server.schemas.analyses import ReportCell, ReportPublic
from server.services import analyses
from server.services.errors import NotFoundError
from server.services.report_tables import FIGURE_CAPTIONS, build_report, predicted_of
from server.services.summary import command_outcome
from server.storage import alarms as alarm_repo
from server.storage import repository as repo
from server.storage._common import MAX_LIMIT

__all__ = [
    "FIGURE_CAPTIONS",
    "analyses_not_run",
    "build_report",
    "pass_report",
    "pass_report_html",
    "pass_report_json",
    "render_html",
    "stored_report",
]


def _cell(value: ReportCell) -> str:
    if value is None:
        return "&ndash;"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.5g}"
    return html.escape(str(value))


_STYLE = """
body { font-family: system-ui, sans-serif; margin: 2em; color: #222; }
table { border-collapse: collapse; margin: 0.5em 0 1.5em; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.2em 0.5em; text-align: right; }
th { background: #f2f2f2; } td:first-child, th:first-child { text-align: left; }
.failed, .not-reproduced { color: #a00; } .not-measured { color: #777; }
figure { margin: 1em 0; } img { max-width: 100%; }
"""


_VERDICT_CLASS = {"not reproduced": "not-reproduced", "not measured": "not-measured"}


def render_html(report: ReportPublic, image_src: Mapping[str, str]) -> str:
    """One HTML page of ``report``; ``image_src`` gives each figure's ``src`` (a data: URI
    for the server, a file name next to the page for the command line). Every text from the
    report is escaped."""
    e = html.escape
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>Pass report: {e(report.name)}</title><style>{_STYLE}</style></head><body>",
        f"<h1>Pass report: {e(report.name)}</h1>",
        "<p>",
        f"pass {e(report.pass_id or '(from a file)')}; experiment {e(report.experiment)}; "
        f"state {e(report.state or 'unknown')}{'; imported' if report.imported else ''}",
        "</p><h2>Analyses</h2><ul>",
    ]
    for status in report.analyses:
        when = "" if status.created_at is None else f" ({status.created_at.isoformat()})"
        cls = ' class="failed"' if status.status != "ok" else ""
        why = "" if status.error is None else f": {e(status.error)}"
        parts.append(f"<li{cls}>{e(status.kind)}: {e(status.status)}{e(when)}{why}</li>")
    parts.append("</ul>")
    for table in report.tables:
        parts.append(f'<h2 id="{e(table.id)}">{e(table.title)}</h2><table><thead><tr>')
        parts += [f"<th>{e(c)}</th>" for c in table.columns]
        parts.append("</tr></thead><tbody>")
        for row in table.rows:
            graded = table.id in ("flight_against_ours", "plan_against_ours")
            verdict = str(row[-1]) if graded and row else ""
            attr = f' class="{_VERDICT_CLASS[verdict]}"' if verdict in _VERDICT_CLASS else ""
            parts.append(f"<tr{attr}>" + "".join(f"<td>{_cell(v)}</td>" for v in row) + "</tr>")
        parts.append("</tbody></table>")
        parts += [f"<p>{e(note)}</p>" for note in table.notes]
    if report.figures:
        parts.append("<h2>Figures</h2>")
    for name in report.figures:
        caption = FIGURE_CAPTIONS.get(name, name)
        src = image_src.get(name, "")
        parts.append(
            f'<figure id="figure-{e(name)}"><img src="{e(src)}" alt="{e(caption)}">'
            f"<figcaption>{e(caption)}</figcaption></figure>"
        )
    parts.append("</body></html>\n")
    return "\n".join(parts)


def analyses_not_run(pass_id: str) -> NotFoundError:
    """The refusal for a report of a pass whose analyses have not run."""
    return NotFoundError(
        "analysis_not_run",
        f"pass {pass_id} has no analyses yet: POST /api/passes/{pass_id}/analyses",
    )


def stored_report(session: Session, pass_id: str) -> tuple[ReportPublic, dict[str, bytes]]:
    """The report of the pass's newest analyses and their figures (PNG bytes by name);
    ``NotFoundError`` ``analysis_not_run`` before the first run."""
    record = repo.get_pass(session=session, pass_id=pass_id)
    rows = analyses.newest_documents(session=session, pass_id=record.id)
    if not rows:
        raise analyses_not_run(record.id)
    figures = analyses.figures(session=session, pass_id=record.id)
    imported = repo.list_events(
        session=session, pass_id=record.id, kinds=["pass_imported"], limit=1
    ).count
    alarms = alarm_repo.list_alarms(session=session, pass_id=record.id, limit=MAX_LIMIT).items
    plan = repo.get_plan(session=session, plan_id=record.plan_id)
    plan_doc = json.loads(plan.document)
    report = build_report(
        pass_id=record.id,
        name=record.name,
        state=record.state,
        experiment=plan.experiment,
        imported=imported > 0,
        documents={kind: (r.result, r.created_at_ns) for kind, r in rows.items()},
        figure_names=list(figures),
        alarms=[alarm_repo.stored_alarm(a) for a in reversed(alarms)],
        epoch_ns=record.epoch_ns,
        # a pass flown here (an imported one's report is its recording's, as from the file)
        commands=None if imported else command_outcome(session, record.id).document(),
        plan=predicted_of(plan_doc if isinstance(plan_doc, Mapping) else {}),
    )
    return report, figures


def pass_report(*, session: Session, pass_id: str) -> ReportPublic:
    """The report of the pass's newest analyses (see :func:`stored_report`)."""
    return stored_report(session, pass_id)[0]


def pass_report_json(*, session: Session, pass_id: str) -> bytes:
    """The report as the JSON the API answers (FastAPI's rendering of :class:`ReportPublic`:
    compact, UTF-8, no NaN)."""
    document = pass_report(session=session, pass_id=pass_id).model_dump(mode="json", by_alias=True)
    text = json.dumps(document, ensure_ascii=False, allow_nan=False, separators=(",", ":"))
    return text.encode("utf-8")


def pass_report_html(*, session: Session, pass_id: str) -> str:
    """The report as one self-contained HTML page (figures as data: URIs)."""
    report, figures = stored_report(session, pass_id)
    sources = {
        name: "data:image/png;base64," + base64.b64encode(png).decode("ascii")
        for name, png in figures.items()
    }
    return render_html(report, sources)
