"""A plan document from outside (``hikoboshi plan ... --out p.json``, ``POST
/api/plans/documents``) read as hostile input: every refusal the invalid request
``invalid_plan_document`` with its reason, before anything is stored.

    read_document(data, max_bytes=, max_depth=) -> Plan     the file's bytes, checked
    description_for_document(plan, robot_files) -> RobotDescription   its robot, by hash

What is refused: more than ``max_bytes``; not UTF-8 JSON; ``NaN``, ``Infinity`` or a number
too large for a float; nesting deeper than ``max_depth``; text the databases do not store
(:func:`server.schemas.json_text.json_problem`); anything :class:`planner.plan.Plan` refuses
when it reads a document (command tags exactly 0.25 s apart, known segment kinds and
attitude-control modes, a 64-digit robot hash) or when it checks one read from outside
(:meth:`planner.plan.Plan.check_consistent`: tags on the 4 Hz grid, attitude commands in time
order, a prediction row per command). A robot the server has no description of is
``unknown_robot``. The document's own flight-rules report is read and then thrown away: the
ground checks the plan again (:func:`server.operations.planning.check`).

    with_ground_prediction(plan, description) -> Plan   the ground's prediction, or refused

Nor is its prediction trusted: the ground predicts the plan again from its commands and its
stated start with the planner's own prediction (:func:`planner.reprediction.repredict`) for
the robot the document names, and refuses a document whose prediction differs from it by more
than :data:`planner.reprediction.PREDICTION_TOLERANCE` in any value (``invalid_plan_document``
naming the quantity, the time and both values; ``detail``: the same as fields). A document
within it is stored with the ground's prediction in place of its own, so that the rules, the
stored plan and a later re-check all read the one prediction the ground made.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, NoReturn

from server.schemas.json_text import json_problem
from server.services.errors import ConflictError, InvalidRequestError
from server.services.robots import description_for_plan

if TYPE_CHECKING:
    from planner.plan import Plan
    from planner.robot import RobotDescription

__all__ = [
    "INVALID_PLAN_DOCUMENT",
    "UNKNOWN_ROBOT",
    "description_for_document",
    "document_schema",
    "read_document",
    "with_ground_prediction",
]

INVALID_PLAN_DOCUMENT = "invalid_plan_document"
#: As for a request naming a robot the server does not know (server.services.robots).
UNKNOWN_ROBOT = "unknown_robot"


def _refuse(reason: str, detail: object = None) -> NoReturn:
    raise InvalidRequestError(INVALID_PLAN_DOCUMENT, f"the plan document: {reason}", detail)


def _not_a_number(text: str) -> float:
    raise ValueError(f"{text} is not a number a plan may hold")


def _finite(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(f"{text} is too large for a float")
    return value


def read_document(data: bytes, *, max_bytes: int, max_depth: int) -> Plan:
    """The plan in ``data`` (a document as ``Plan.to_json`` writes it), every check of the
    module docstring passed; its ``flight_rules`` as written (not to be trusted)."""
    from planner.errors import PlannerError
    from planner.plan import DOCUMENT_KEYS, Plan

    if len(data) > max_bytes:
        _refuse(f"{len(data)} bytes, over the limit of {max_bytes}")
    try:
        doc = json.loads(data, parse_constant=_not_a_number, parse_float=_finite)
    except RecursionError:
        _refuse(f"nested deeper than {max_depth}")
    except ValueError as exc:  # JSONDecodeError, UnicodeDecodeError, ours
        _refuse(f"not JSON a plan may hold: {exc}")
    problem = json_problem(doc, max_depth, "document")
    if problem is not None:
        _refuse(problem[1], problem[2])
    if not isinstance(doc, dict):
        _refuse("a plan is a JSON object")
    unknown = sorted(set(doc) - set(DOCUMENT_KEYS))
    if unknown:
        _refuse(f"unknown keys {unknown} (a plan has {list(DOCUMENT_KEYS)})")
    try:
        plan = Plan.from_dict(doc)
        plan.check_consistent()
    except PlannerError as exc:
        _refuse(str(exc))
    except (ArithmeticError, ValueError, TypeError) as exc:
        _refuse(f"malformed: {exc!r}")
    return plan


def document_schema() -> dict[str, object]:
    """The document's JSON schema as the API declares it: its keys, no others."""
    from planner.plan import DOCUMENT_KEYS

    return {
        "type": "object",
        "description": "A plan document as hikoboshi plan ... --out FILE writes it "
        "(planner.plan.Plan.to_json; GET /api/plans/{id}/document gives one back)",
        "properties": {key: {} for key in DOCUMENT_KEYS},
        # a document without a robot is ETS-VII's; one without a report was never checked
        "required": [k for k in DOCUMENT_KEYS if k not in ("robot", "robot_hash", "flight_rules")],
        "additionalProperties": False,
    }


def description_for_document(
    plan: Plan, robot_files: Sequence[Path | str] = ()
) -> RobotDescription:
    """The description of the robot ``plan`` names by its hash (ETS-VII's built in, the
    shipped ones and ``robot_files``); ``unknown_robot`` when the server has none."""
    try:
        return description_for_plan(plan, robot_files)
    except ConflictError as exc:
        raise InvalidRequestError(UNKNOWN_ROBOT, exc.message) from None


def with_ground_prediction(plan: Plan, description: RobotDescription) -> Plan:
    """``plan`` carrying the ground's prediction of it (module docstring); refused with
    ``invalid_plan_document`` when its own prediction differs from that one, or when it
    cannot be predicted on ``description``'s model (its joints are not the robot's)."""
    from planner.dynamics import DynamicsWorkspace
    from planner.errors import PlannerError
    from planner.reprediction import prediction_difference, repredict

    try:
        ws = DynamicsWorkspace(description.model)
        ground = repredict(
            plan, ws, acs_gains=description.acs_gains(ws), servo_gains=description.servo_gains()
        )
    except PlannerError as exc:
        _refuse(f"cannot be predicted for robot {description.name!r}: {exc}")
    except (ArithmeticError, ValueError, IndexError) as exc:
        _refuse(f"cannot be predicted for robot {description.name!r}: {exc!r}")
    difference = prediction_difference(plan.prediction, ground)
    if difference is not None:
        _refuse(f"its prediction is not the ground's: {difference}", difference.to_dict())
    return replace(plan, prediction=ground)
