"""Post-pass analyses of a stored pass, run on request and kept in ``analysis_results``.

One run analyses the pass's recording (:func:`server.services.recordings.load_recording`)
three ways and stores one row of each kind, plus the figures:

    pass_analysis            telemetry.analysis.analyse_pass: every experiment that applies,
                             predicted against flown
    inertia_identification   telemetry.identification.identify_base_inertia, with the model's
                             base inertia (the simulator's truth, Table 1) as the reference
    gravity_gradient_resim   telemetry.resim.resimulate_free_drift: free drift re-simulated
                             with and without eq. (11)
    flown_clearance          server.services.clearance.flown_clearance: the least clearance
                             between the robot's bodies at the measured joints, beside the
                             one the plan's flight rules predicted
    report_figures           the PNGs of telemetry.figures.pass_figures (base64), and the
                             alarm timeline's when the pass has alarms, so a report is a
                             read, never a re-analysis

Each row's ``result`` is ``{"status": "ok", "result": NUMBERS}`` or ``{"status": "failed",
"error": {"type", "message"}}``: an analysis that cannot run on a pass (too little
telemetry, no free drift) is stored as such, and the others are still stored.

What is stored: the numbers, not the per-sample series. ``analyse_pass(...).to_dict()`` is
6.6 MB on the 20-minute demo pass, almost all of it ``series`` (the curves behind the
figures, resampled telemetry); the resim adds 0.4 MB of re-simulated quaternions. They are a
deterministic function of the telemetry, which the database already holds in full, and they
would be written again at every re-run; a client that wants curves reads the telemetry
(raw or decimated) or the figures. Without them the three results are about 35 KB.

A run holds no database transaction while it computes (several seconds for a whole pass):
on SQLite every transaction holds the write lock, and the link must keep storing frames.
"""

from __future__ import annotations

import base64
import json
import logging
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sqlalchemy.orm import Session

from planner.dynamics import DynamicsWorkspace
from planner.model import INERTIA_PRODUCT_SIGN, RobotModel, default_model
from server.schemas import iso_from_ns
from server.schemas.analyses import AnalysesPublic, AnalysisErrorPublic, AnalysisPublic
from server.services.clearance import flown_clearance
from server.services.errors import NotFoundError
from server.services.events import AnalysesRun
from server.services.events import record as record_event
from server.services.recordings import load_recording
from server.services.robots import description_for_plan, model_for_plan
from server.storage import repository as repo
from server.storage.errors import NotFound
from server.storage.models import AnalysisRecord
from telemetry.analysis import PassAnalysis, analyse_pass
from telemetry.identification import (
    INERTIA_PARAMETER_NAMES,
    InsufficientData,
    NotPositiveDefinite,
)
from telemetry.identification import identify_base_inertia as identify
from telemetry.recording import PassRecording, UnphysicalTelemetry, check_physical
from telemetry.resim import resimulate_free_drift

__all__ = [
    "FIGURES_KIND",
    "KINDS",
    "SERIES_KEYS",
    "AnalysisRun",
    "compute_analyses",
    "figure_png",
    "figures",
    "get_analysis",
    "list_analyses",
    "newest_documents",
    "numbers_only",
    "run_analyses",
]

log = logging.getLogger(__name__)

KINDS = ("pass_analysis", "inertia_identification", "gravity_gradient_resim", "flown_clearance")
FIGURES_KIND = "report_figures"
#: Keys whose list or object values are per-sample series, left out of stored results.
SERIES_KEYS = frozenset({"series", "t_s", "quat_orbit_from_base_xyzw"})
REFERENCE_SOURCE = "model base inertia (Table 1; the simulator's truth)"


def numbers_only(doc: Any) -> Any:
    """``doc`` without the values of :data:`SERIES_KEYS` that are lists or objects."""
    if isinstance(doc, dict):
        return {
            k: numbers_only(v)
            for k, v in doc.items()
            if not (k in SERIES_KEYS and isinstance(v, list | dict))
        }
    if isinstance(doc, list):
        return [numbers_only(v) for v in doc]
    return doc


@dataclass(frozen=True)
class AnalysisRun:
    """The stored documents of one run (by kind) and the figures (PNG bytes by name)."""

    documents: dict[str, dict[str, Any]]
    figures: dict[str, bytes] = field(default_factory=dict)


def _reference_parameters(model: RobotModel) -> dict[str, float]:
    i = model.base_inertia_kgm2
    s = INERTIA_PRODUCT_SIGN
    values = (i[0, 0], i[1, 1], i[2, 2], s * i[0, 1], s * i[0, 2], s * i[1, 2])
    return {n: float(v) for n, v in zip(INERTIA_PARAMETER_NAMES, values, strict=True)}


def _attempt(kind: str, run: Callable[[], Any]) -> tuple[Any, dict[str, Any]]:
    """``(value, document)``; a failure becomes a ``failed`` document naming the cause. Any
    exception: one analysis that cannot cope with a pass must not cost the others."""
    try:
        value = run()
        result = numbers_only(value.to_dict())
        json.dumps(result, allow_nan=False)  # NaN or infinity: not storable JSON
    except Exception as exc:
        expected = (InsufficientData, UnphysicalTelemetry, NotPositiveDefinite)
        log.warning("analysis %s failed", kind, exc_info=not isinstance(exc, expected))
        error = {"type": type(exc).__name__, "message": str(exc) or repr(exc)}
        return None, {"status": "failed", "error": error}
    return value, {"status": "ok", "result": result}


def _diverged(recording: PassRecording) -> UnphysicalTelemetry | None:
    """The vehicle's own word that its truth simulation diverged during the pass (a
    ``vehicle_safed`` event with the trigger ``simulation_diverged``): nothing of the pass
    is a flight to analyse."""
    for event in recording.events:
        trigger = event.detail.get("trigger") if event.kind == "vehicle_safed" else None
        if isinstance(trigger, Mapping) and trigger.get("quantity") == "simulation_diverged":
            return UnphysicalTelemetry(
                f"the vehicle reported its simulation diverged (safed at onboard "
                f"{event.detail.get('since_time_ns')}: {trigger.get('detail')}): a diverged "
                "simulation is not analysed"
            )
    return None


def compute_analyses(
    recording: PassRecording,
    model: RobotModel | None = None,
    robot_files: Sequence[str] = (),
) -> AnalysisRun:
    """Run every analysis on ``recording`` and draw the figures (pure: no database). The
    flown clearance needs the plan's robot description (ETS-VII's built in; another found
    by its hash among the shipped ones and ``robot_files``)."""
    model = model or default_model()
    n = len(recording.frames)
    try:
        check_physical(recording.frames)
        unphysical: UnphysicalTelemetry | None = _diverged(recording)
    except UnphysicalTelemetry as exc:
        unphysical = exc

    def physical() -> None:
        """Every analysis fails, with the reason, on a recording no vehicle can have made."""
        if unphysical is not None:
            raise unphysical

    def enough() -> None:
        physical()
        if n < 3:
            raise InsufficientData(f"the pass has {n} telemetry frames (need 3 or more)")

    def identification() -> Any:
        enough()
        return identify(recording, model)

    def resim() -> Any:
        enough()
        return resimulate_free_drift(recording, model)

    ws = DynamicsWorkspace(model)

    def passes() -> Any:
        physical()
        if n == 0:  # nothing flown is stored: no result, not an empty "ok"
            raise InsufficientData("the pass has no telemetry frames")
        return analyse_pass(recording, ws)

    analysis, pass_doc = _attempt("pass_analysis", passes)
    _, ident_doc = _attempt("inertia_identification", identification)
    if ident_doc["status"] == "ok":
        ident_doc["result"]["reference"] = {
            "source": REFERENCE_SOURCE,
            "parameters_kgm2": _reference_parameters(model),
        }
    _, resim_doc = _attempt("gravity_gradient_resim", resim)

    def clearance() -> Any:
        physical()
        description = description_for_plan(recording.plan, [Path(p) for p in robot_files])
        return flown_clearance(recording, description)

    _, clearance_doc = _attempt("flown_clearance", clearance)
    # matplotlib: imported by the worker that draws, not at the ground's start
    from telemetry.figures import alarm_timeline_figure, pass_figures

    figures: dict[str, bytes] = {}
    if isinstance(analysis, PassAnalysis):
        try:
            figures = pass_figures(analysis)
        except Exception:  # a figure is not worth losing the numbers for
            log.exception("figures of pass %r failed", recording.name)
    if recording.alarms:
        t_s = recording.t_s()
        end_t_s = float(t_s[-1]) if len(t_s) else recording.plan.duration_s
        try:
            figures["alarm_timeline"] = alarm_timeline_figure(
                recording.alarms, recording.epoch_ns, end_t_s
            )
        except Exception:
            log.exception("the alarm timeline of pass %r failed", recording.name)
    return AnalysisRun(
        documents={
            "pass_analysis": pass_doc,
            "inertia_identification": ident_doc,
            "gravity_gradient_resim": resim_doc,
            "flown_clearance": clearance_doc,
        },
        figures=figures,
    )


def _public(record: AnalysisRecord) -> AnalysisPublic:
    doc = record.result
    error = doc.get("error")
    return AnalysisPublic(
        id=record.id,
        pass_id=record.pass_id,
        kind=record.kind,
        created_at=iso_from_ns(record.created_at_ns),
        status="ok" if doc.get("status") == "ok" else "failed",
        error=None if error is None else AnalysisErrorPublic(**error),
        result=doc.get("result"),
    )


def run_analyses(
    *,
    session: Session,
    pass_id: str,
    actor: str,
    model: RobotModel | None = None,
    now_ns: int | None = None,
    robot_files: tuple[str, ...] = (),
) -> AnalysesPublic:
    """Analyse the pass afresh and store the results (see the module doc); storage's ``NotFound``
    for an unknown pass, :class:`~server.services.recordings.NotFlown` for one not flown. The audit
    event ``analyses_run`` names who asked. Without ``model``, the model of the plan's robot
    (:func:`server.services.robots.model_for_plan`, among the shipped descriptions and
    ``robot_files``)."""
    recording = load_recording(session=session, pass_id=pass_id)
    key = str(recording.meta["pass_id"])
    session.rollback()  # end the read: no transaction (no SQLite write lock) while computing
    run = compute_analyses(
        recording, model or model_for_plan(recording.plan, robot_files), robot_files
    )
    now_ns = time.time_ns() if now_ns is None else now_ns
    try:
        records = [
            repo.add_analysis(
                session=session, pass_id=key, kind=kind, result=doc, created_at_ns=now_ns
            )
            for kind, doc in run.documents.items()
        ]
        images = {name: base64.b64encode(png).decode("ascii") for name, png in run.figures.items()}
        repo.add_analysis(
            session=session,
            pass_id=key,
            kind=FIGURES_KIND,
            result={"status": "ok", "format": "png", "images": images},
            created_at_ns=now_ns,
        )
        statuses = {kind: doc["status"] for kind, doc in run.documents.items()}
        record_event(session, AnalysesRun(actor=actor, pass_id=key, statuses=statuses), now_ns)
        session.commit()
    except BaseException:
        session.rollback()
        raise
    data = [_public(r) for r in records]
    return AnalysesPublic(data=data, count=len(data))


def _newest(session: Session, pass_id: str, kind: str) -> AnalysisRecord | None:
    try:
        return repo.get_analysis(session=session, pass_id=pass_id, kind=kind)
    except NotFound:
        return None


def newest_documents(*, session: Session, pass_id: str) -> dict[str, AnalysisRecord]:
    """The newest stored row of each kind in :data:`KINDS` (absent kinds left out)."""
    key = repo.get_pass(session=session, pass_id=pass_id).id
    found = {kind: _newest(session, key, kind) for kind in KINDS}
    return {kind: record for kind, record in found.items() if record is not None}


def list_analyses(*, session: Session, pass_id: str) -> AnalysesPublic:
    """The newest analysis of each kind (none before the first run)."""
    data = [_public(r) for r in newest_documents(session=session, pass_id=pass_id).values()]
    return AnalysesPublic(data=data, count=len(data))


def get_analysis(*, session: Session, pass_id: str, kind: str) -> AnalysisPublic:
    """The newest analysis of ``kind``; ``NotFoundError`` if the pass has none."""
    record = newest_documents(session=session, pass_id=pass_id).get(kind)
    if record is None:
        raise NotFoundError(
            "analysis_not_run", f"no {kind} analysis of pass {pass_id}: run the analyses"
        )
    return _public(record)


def figures(*, session: Session, pass_id: str) -> dict[str, bytes]:
    """The newest run's figures, PNG bytes by name (empty before the first run)."""
    key = repo.get_pass(session=session, pass_id=pass_id).id
    record = _newest(session, key, FIGURES_KIND)
    images: Mapping[str, str] = {} if record is None else record.result.get("images", {})
    return {name: base64.b64decode(data) for name, data in images.items()}


def figure_png(*, session: Session, pass_id: str, name: str) -> bytes:
    """One figure of the newest run; ``NotFoundError`` when there is none of that name."""
    found = figures(session=session, pass_id=pass_id)
    if name not in found:
        known = ", ".join(sorted(found)) or "none: run the analyses"
        raise NotFoundError(
            "figure_not_found", f"pass {pass_id} has no figure {name!r} (figures: {known})"
        )
    return found[name]
