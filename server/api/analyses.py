"""``/api/passes/{id}/analyses`` and ``/report``: run the post-pass analyses (operator),
read the newest results, the report as JSON or HTML and its figures (viewer)."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Path
from fastapi.responses import HTMLResponse, Response

from server.api.deps import OperatorDep, SessionDep, ViewerDep
from server.schemas import (
    ERROR_RESPONSES,
    AnalysesPublic,
    AnalysisKind,
    AnalysisPublic,
    ReportPublic,
)
from server.services import analyses as service
from server.services import reports

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
def run_analyses(pass_id: str, session: SessionDep, who: OperatorDep) -> AnalysesPublic:
    """Analyse the flown pass afresh (seconds for a whole pass) and store one result of each
    kind; an analysis that cannot run on this pass is stored as failed, with the reason."""
    return service.run_analyses(session=session, pass_id=pass_id, actor=who.name)


@router.get("/{pass_id}/analyses", response_model=AnalysesPublic)
def list_analyses(pass_id: str, session: SessionDep, _: ViewerDep) -> AnalysesPublic:
    """The newest result of each kind (none before the first run)."""
    return service.list_analyses(session=session, pass_id=pass_id)


@router.get("/{pass_id}/analyses/{kind}", response_model=AnalysisPublic)
def get_analysis(
    pass_id: str, kind: AnalysisKind, session: SessionDep, _: ViewerDep
) -> AnalysisPublic:
    return service.get_analysis(session=session, pass_id=pass_id, kind=kind)


@router.get("/{pass_id}/report", response_model=ReportPublic)
def get_report(pass_id: str, session: SessionDep, _: ViewerDep) -> ReportPublic:
    """The newest analyses as tables: predicted against flown, the experiments, the
    identified inertia against the model's, gravity-gradient residuals with and without."""
    return reports.pass_report(session=session, pass_id=pass_id)


@router.get(
    "/{pass_id}/report.html",
    response_class=HTMLResponse,
    responses={
        **_JSON_ERRORS,
        200: {"content": {"text/html": {}}, "description": "One self-contained page"},
    },
)
def get_report_html(pass_id: str, session: SessionDep, _: ViewerDep) -> HTMLResponse:
    """The report as one HTML page with its figures inline (data: URIs), so a page fetched
    with a token needs nothing else."""
    page = reports.pass_report_html(session=session, pass_id=pass_id)
    return HTMLResponse(page, headers={"Content-Security-Policy": _HTML_POLICY})


@router.get(
    "/{pass_id}/report/figures/{name}.png",
    response_class=Response,
    responses={200: {"content": {"image/png": {}}, "description": "The figure"}},
)
def get_figure(
    pass_id: str,
    name: Annotated[str, Path(max_length=64)],
    session: SessionDep,
    _: ViewerDep,
) -> Response:
    """One figure of the newest run, PNG."""
    png = service.figure_png(session=session, pass_id=pass_id, name=name)
    return Response(png, media_type="image/png")
