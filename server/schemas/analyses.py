"""The REST API's post-pass analyses, pass reports and imported recordings
(``/api/passes/{id}/analyses``, ``/report``, ``/api/passes/import``: docs/analysis.md)."""

from __future__ import annotations

from datetime import datetime
from typing import Any, Literal

from pydantic import BaseModel, Field

from server.schemas.passes import PassPublic

__all__ = [
    "AnalysesPublic",
    "AnalysisErrorPublic",
    "AnalysisKind",
    "AnalysisPublic",
    "PassImportPublic",
    "ReportAnalysisPublic",
    "ReportCell",
    "ReportPublic",
    "ReportTablePublic",
]


#: The stored post-pass analyses (server.services.analyses), one row of each per run.
AnalysisKind = Literal[
    "pass_analysis", "inertia_identification", "gravity_gradient_resim", "flown_clearance"
]
ReportCell = float | int | str | bool | None


class AnalysisErrorPublic(BaseModel):
    """Why an analysis gave no result: the exception's class and message."""

    type: str
    message: str


class AnalysisPublic(BaseModel):
    """One stored analysis run of a pass: its numbers (``status == "ok"``) or why it failed.
    ``result`` holds the analysis's ``to_dict()`` without its per-sample series."""

    id: int
    pass_id: str
    kind: str
    created_at: datetime
    status: Literal["ok", "failed"]
    error: AnalysisErrorPublic | None = None
    result: dict[str, Any] | None = None


class AnalysesPublic(BaseModel):
    data: list[AnalysisPublic]
    count: int


class ReportTablePublic(BaseModel):
    """One table of a report: ``rows`` of cells in ``columns`` order (units in the names)."""

    id: str
    title: str
    columns: list[str]
    rows: list[list[ReportCell]]
    notes: list[str] = Field(default_factory=list)


class ReportAnalysisPublic(BaseModel):
    kind: str
    status: Literal["ok", "failed", "absent"]
    created_at: datetime | None = None
    error: str | None = None


class ReportPublic(BaseModel):
    """A pass report: the newest stored analyses as tables, and the figures' names
    (``GET /api/passes/{id}/report/figures/{name}.png``)."""

    pass_id: str | None
    name: str
    state: str | None
    experiment: str
    imported: bool
    analyses: list[ReportAnalysisPublic]
    tables: list[ReportTablePublic]
    figures: list[str]


class PassImportPublic(BaseModel):
    """The pass an uploaded recording became, and what was stored of it."""

    imported: PassPublic
    frames: int
    commands: int
    events: int
