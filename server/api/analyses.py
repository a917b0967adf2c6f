"""``/api/passes/{id}/analyses`` and ``/report``: run the post-pass analyses (operator),
read the newest results, the report as JSON or HTML and its figures (viewer).

Running the analyses happens in a worker process (:mod:`server.services.workers`) on its
own database connection. The report (JSON, HTML) and its figures (they decode and
re-encode every figure of the run) are computed there once per content version, stored
and served from the file to every viewer (:mod:`server.services.artifacts`; the version is
the ``ETag``). A full pool answers 503 ``busy`` with ``Retry-After``; past
``read_deadline_s`` (the analyses: ``post_pass_deadline_s``), 504."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Path, Request
from fastapi.responses import HTMLResponse, Response

from server.api.deps import IdPath, OperatorDep, SessionDep, ViewerDep
from server.api.jobs import JobsDep
from server.api.openapi import file_content
from server.api.served import NOT_MODIFIED, ArtifactsDep, serve_artifact
from server.schemas import ERROR_RESPONSES, SafeLine
from server.schemas.analyses import AnalysesPublic, AnalysisKind, AnalysisPublic, ReportPublic
from server.services import analyses as service
from server.services.artifacts import ArtifactRef

__all__ = ["router"]

router = APIRouter(prefix="/api/passes", tags=["analyses"], responses=ERROR_RESPONSES)

#: The served page holds only inline style and data: images; nothing else may load.
_HTML_POLICY = "default-src 'none'; img-src data:; style-src 'unsafe-inline'"
#: Errors stay JSON on the HTML route (FastAPI would document them as the route's text/html).
_JSON_ERRORS: dict[int | str, dict[str, Any]] = {
    status: {
        "description": response["description"],
        "content": {"application/json": {"schema": {"$ref": "#/components/schemas/ErrorPublic"}}},
    }
    for status, response in ERROR_RESPONSES.items()
}


@router.post("/{pass_id}/analyses", status_code=201, response_model=AnalysesPublic)
async def run_analyses(pass_id: IdPath, who: OperatorDep, jobs: JobsDep) -> AnalysesPublic:
    """Analyse the flown pass afresh (tens of seconds for a whole pass, in a worker process
    on its own connection; past ``post_pass_deadline_s``, 504) and store one result of each
    kind; an analysis that cannot run on this pass is stored as failed, with the reason."""
    return await jobs.written(
        service.run_analyses,
        pass_id=pass_id,
        actor=who.name,
        robot_files=jobs.robot_files,
        deadline_s=jobs.settings.post_pass_deadline_s,
        what=f"the analyses of pass {pass_id}",
    )


@router.get("/{pass_id}/analyses", response_model=AnalysesPublic)
def list_analyses(pass_id: IdPath, session: SessionDep, _: ViewerDep) -> AnalysesPublic:
    """The newest result of each kind (none before the first run)."""
    return service.list_analyses(session=session, pass_id=pass_id)


@router.get("/{pass_id}/analyses/{kind}", response_model=AnalysisPublic)
def get_analysis(
    pass_id: IdPath, kind: AnalysisKind, session: SessionDep, _: ViewerDep
) -> AnalysisPublic:
    return service.get_analysis(session=session, pass_id=pass_id, kind=kind)


@router.get(
    "/{pass_id}/report",
    response_model=ReportPublic,
    responses={**NOT_MODIFIED},
)
async def get_report(
    pass_id: IdPath, http: Request, _: ViewerDep, artifacts: ArtifactsDep
) -> Response:
    """The newest analyses as tables: predicted against flown, the experiments, the
    identified inertia against the model's, gravity-gradient residuals with and without."""
    return await serve_artifact(http, artifacts, ArtifactRef("report", pass_id), "application/json")


@router.get(
    "/{pass_id}/report.html",
    response_class=HTMLResponse,
    responses={
        **_JSON_ERRORS,
        200: {
            "content": file_content("text/html", text=True),
            "description": "One self-contained page",
        },
        **NOT_MODIFIED,
    },
)
async def get_report_html(
    pass_id: IdPath, http: Request, _: ViewerDep, artifacts: ArtifactsDep
) -> Response:
    """The report as one HTML page with its figures inline (data: URIs), so a page fetched
    with a token needs nothing else."""
    return await serve_artifact(
        http,
        artifacts,
        ArtifactRef("report_html", pass_id),
        "text/html; charset=utf-8",
        {"Content-Security-Policy": _HTML_POLICY},
    )


@router.get(
    "/{pass_id}/report/figures/{name}.png",
    response_class=Response,
    responses={
        200: {"content": file_content("image/png"), "description": "The figure"},
        **NOT_MODIFIED,
    },
)
async def get_figure(
    pass_id: IdPath,
    name: Annotated[SafeLine, Path(min_length=1, max_length=64)],
    http: Request,
    _: ViewerDep,
    artifacts: ArtifactsDep,
) -> Response:
    """One figure of the newest run, PNG."""
    return await serve_artifact(http, artifacts, ArtifactRef("figure", pass_id, name), "image/png")
