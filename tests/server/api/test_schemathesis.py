"""A schemathesis run of the whole REST API from its own OpenAPI document, on each backend:
what the CLI's ``schemathesis run`` does (its engine: the examples, coverage and fuzzing
phases), in process, with every check schemathesis has enabled, a fixed seed, derandomized
generation and a fixed number of examples per operation. It passes with no failure: no 5xx,
every status and body as documented, ``Allow`` on ``OPTIONS`` and on 405, and no
schema-valid request refused, beyond the exclusions below, each with its reason (the same
list is in docs/security.md, *The OpenAPI document*).

Exclusions, each narrowed to its operation, status and error codes (the check
``excused_refusals_are_the_documented_ones`` fails any other code under the same status):

- ``POST /api/vehicle/safe-exit`` 503 ``link_down`` (``not_a_server_error``): no spacecraft
  is connected here, and that is the route's documented refusal (nothing can reach the
  vehicle; ``Retry-After``), not a failure of the server.
- ``POST /api/plans`` 422 with the planner's refusals (``positive_data_acceptance``): an
  experiment's parameter names, ranges and feasibility are the planner's, per experiment
  and per robot (``planner/parameters.py``), and no JSON Schema states whether a goal can
  be reached; ``unknown_robot``: the robots are the server's files.
- ``POST /api/passes`` 422 ``window_reversed``, ``time_out_of_range``: rules between two
  fields (los after aos) and a date-time range, none of which JSON Schema states (a window
  too short for the stored plan is a conflict, 409 ``plan_exceeds_window``).
- ``GET /api/passes/{pass_id}/telemetry`` 422 ``empty_range``, ``unknown_field``,
  ``repeated_field``: ``t1`` after ``t0`` and the fields of the pass's robot.
- ``POST /api/passes/import`` 422 ``invalid_recording``: the body is an MCAP file, which a
  schema can call binary but not check.
- ``POST /api/plans/documents`` 422 ``invalid_plan_document``, ``unknown_robot``: a plan's
  numbers agree with each other (a prediction row per command, tags on the 4 Hz grid) and
  its robot hash is one of the server's files, which no JSON Schema states.
- ``GET /api/windows`` and ``POST /api/passes`` 422 ``span_outside_elements``: a time more
  than 60 days from the mission's elements' epoch, which is the mission file's, not the
  schema's.

The coverage phase runs on SQLite only, the fuzzing phase on PostgreSQL only (every
operation called with generated data, accepted and refused); both get the examples phase.
Each of the two calls every operation. The coverage phase is
an enumeration of the schema (each boundary, each missing or wrong-typed field, each
unexpected method): 1,419 cases, 1,039 of them schema-invalid, which validation refuses
before any storage is reached, and on PostgreSQL 48 of its 110 s went to routes that use
no database (contact windows, plan validation, the robots). What the backends do
differently (ids that are no UUID, free text, times and limits in queries, the rows
written) the fuzzing phase's generated values reach on PostgreSQL, on every operation; on
SQLite the coverage phase's boundaries, missing and wrong-typed fields reach every
operation (the fuzzing phase there as well cost 9 s of a 52 s run, for 108 cases).

Not run: the ``max_response_time`` check (a timed assertion: it needs a limit, and a test
here must not depend on the machine being idle) and the stateful phase (chains of
operations through their links: minutes on this machine, over the suite's budget; the
coverage and fuzzing phases call every operation).

In process: schemathesis calls the ASGI application on its own event loop and runs its
lifespan there (started by the first request, stopped at the end), so the database stays
migrated and reachable; ``auth_failure_limit`` is raised, because the coverage phase sends
requests without a token on purpose and the edge would otherwise lock its address out.
The case counts per phase are printed (``-s``): the closing numbers quoted in docs.
"""

from __future__ import annotations

import json
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
import schemathesis
from schemathesis.config import SchemathesisConfig
from schemathesis.engine import events, from_schema
from schemathesis.python.asgi import shutdown_lifespans

from server.app import create_app
from server.settings import Settings
from tests.support.api import OPERATOR, TOKENS

#: Examples per operation in the fuzzing phase (the examples and coverage phases are
#: enumerations of the schema: their number of cases is the schema's).
EXAMPLES_PER_OPERATION = 3
SEED = 20261127

#: schemathesis's default expected statuses of the two checks an exclusion widens.
_DEFAULT_STATUSES = {
    "not_a_server_error": ["2xx", "3xx", "4xx"],
    "positive_data_acceptance": ["2xx", "3xx", "401", "403", "404", "409", "429", "5xx"],
}


@dataclass(frozen=True)
class Excuse:
    """A refusal schemathesis would count as a failure, allowed with its reason."""

    method: str
    path: str
    check: str
    status: int
    codes: frozenset[str]
    reason: str


PLANNER_REFUSALS = frozenset(
    {
        "InvalidInput",
        "JointLimitExceeded",
        "InfeasibleGoal",
        "DidNotConverge",
        "planning_failed",
        "unknown_robot",
    }
)
EXCUSES = (
    Excuse(
        "POST",
        "/api/vehicle/safe-exit",
        "not_a_server_error",
        503,
        frozenset({"link_down"}),
        "no spacecraft is connected in this test: the documented refusal, with Retry-After",
    ),
    Excuse(
        "POST",
        "/api/plans",
        "positive_data_acceptance",
        422,
        PLANNER_REFUSALS,
        "parameter names, ranges and feasibility are the planner's, per experiment and robot",
    ),
    Excuse(
        "POST",
        "/api/passes",
        "positive_data_acceptance",
        422,
        frozenset({"window_reversed", "time_out_of_range", "span_outside_elements"}),
        "los after aos, a date-time range, a named window's time near its mission's epoch",
    ),
    Excuse(
        "GET",
        "/api/windows",
        "positive_data_acceptance",
        422,
        frozenset({"span_outside_elements"}),
        "a start near the mission's elements' epoch: the mission file's, not the schema's",
    ),
    Excuse(
        "GET",
        "/api/passes/{pass_id}/telemetry",
        "positive_data_acceptance",
        422,
        frozenset({"empty_range", "unknown_field", "repeated_field"}),
        "t1 after t0, and the fields of the pass's robot",
    ),
    Excuse(
        "POST",
        "/api/plans/documents",
        "positive_data_acceptance",
        422,
        frozenset({"invalid_plan_document", "unknown_robot"}),
        "a plan's numbers agree with each other and its robot is one of the server's files",
    ),
    Excuse(
        "POST",
        "/api/passes/import",
        "positive_data_acceptance",
        422,
        frozenset({"invalid_recording"}),
        "an MCAP file: a schema can call it binary, not check it",
    ),
)
_EXCUSED = {(e.method, e.path, e.status): e for e in EXCUSES}
#: How often each exclusion was used, by (method, path, code): printed with the run.
EXCUSED_USES: Counter[tuple[str, str, str]] = Counter()


def _error_code(content: bytes) -> str | None:
    try:
        return str(json.loads(content)["error"]["code"])
    except (ValueError, KeyError, TypeError):
        return None


@schemathesis.check
def excused_refusals_are_the_documented_ones(ctx: Any, response: Any, case: Any) -> bool | None:
    """An excused status answered with another error code than its exclusion names fails:
    an exclusion covers a reason, not a status."""
    excuse = _EXCUSED.get((case.method.upper(), case.path, response.status_code))
    if excuse is None:
        return None
    if excuse.check == "positive_data_acceptance":
        meta = case.meta
        if meta is None or not meta.generation.mode.is_positive:
            return None
    code = _error_code(response.content)
    if code not in excuse.codes:
        raise AssertionError(
            f"{excuse.method} {excuse.path} answered {response.status_code} {code!r}; its "
            f"exclusion covers only {sorted(excuse.codes)} ({excuse.reason})"
        )
    EXCUSED_USES[(excuse.method, excuse.path, code)] += 1
    return True


#: The backend the coverage phase runs on (the module's docstring says why one); the
#: fuzzing phase runs on the other.
COVERAGE_BACKEND = "sqlite"


def _config(backend: str) -> SchemathesisConfig:
    operations = [
        {
            "include-path": e.path,
            "include-method": e.method,
            "checks": {
                e.check: {"expected-statuses": [*_DEFAULT_STATUSES[e.check], str(e.status)]}
            },
        }
        for e in EXCUSES
    ]
    return SchemathesisConfig.from_dict(
        {
            "seed": SEED,
            # planning and the worker processes' first jobs take seconds on a loaded machine
            "request-timeout": 120,
            "headers": dict(OPERATOR),
            "generation": {
                "max-examples": EXAMPLES_PER_OPERATION,
                "deterministic": True,
                "database": "none",
            },
            "phases": {
                "stateful": {"enabled": False},
                "coverage": {"enabled": backend == COVERAGE_BACKEND},
                "fuzzing": {"enabled": backend != COVERAGE_BACKEND},
            },
            "operations": operations,
        }
    )


@dataclass
class Run:
    cases: Counter[str]
    statuses: Counter[int]
    operations: dict[str, set[str]]
    failures: list[str]
    errors: list[str]
    elapsed_s: float
    phase_s: dict[str, float]


def _describe(recorder: Any, case_id: str, check: Any) -> str:
    interaction = recorder.interactions.get(case_id)
    title = check.failure_info.failure.title if check.failure_info else ""
    if interaction is None or interaction.response is None:
        return f"{recorder.label}: {check.name}: {title}"
    request, response = interaction.request, interaction.response
    body = (request.body or b"")[:200]
    return (
        f"{recorder.label}: {check.name}: {title}: {request.method} {request.uri} {body!r} -> "
        f"{response.status_code} {(response.content or b'')[:300]!r}"
    )


def _run(schema: Any) -> Run:
    run = Run(Counter(), Counter(), {}, [], [], 0.0, {})
    start = time.perf_counter()
    started: dict[str, float] = {}
    for event in from_schema(schema).execute():
        if isinstance(event, events.PhaseStarted):
            started[event.phase.name.value] = time.perf_counter()
        elif isinstance(event, events.PhaseFinished):
            phase = event.phase.name.value
            elapsed = time.perf_counter() - started.pop(phase, time.perf_counter())
            run.phase_s[phase] = run.phase_s.get(phase, 0.0) + elapsed
        if isinstance(event, events.ScenarioFinished):
            recorder = event.recorder
            run.cases[event.phase.value] += len(recorder.cases)
            run.operations.setdefault(event.phase.value, set()).add(recorder.label)
            for interaction in recorder.interactions.values():
                if interaction.response is not None:
                    run.statuses[interaction.response.status_code] += 1
            for case_id, checks in recorder.checks.items():
                for check in checks:
                    if check.status.value == "failure":
                        run.failures.append(_describe(recorder, case_id, check))
        elif isinstance(event, events.NonFatalError | events.FatalError):
            run.errors.append(repr(event))
    run.elapsed_s = time.perf_counter() - start
    return run


@pytest.mark.slow
def test_a_schemathesis_run_finds_nothing(
    database_url: str, tmp_path: Path, request: pytest.FixtureRequest
) -> None:
    backend = request.node.callspec.params["database_url"]
    settings = Settings(
        data_dir=tmp_path, database_url=database_url, tokens=TOKENS, auth_failure_limit=10**9
    )
    app = create_app(settings)
    EXCUSED_USES.clear()
    try:
        schema = schemathesis.openapi.from_asgi("/openapi.json", app, config=_config(backend))
        run = _run(schema)
    finally:
        shutdown_lifespans()
    documented = {
        f"{method.upper()} {path}"
        for path, item in app.openapi()["paths"].items()
        for method in item
    }
    total = sum(run.cases.values())
    print(
        f"\nschemathesis on {backend}: {total} cases "
        f"({', '.join(f'{phase} {n}' for phase, n in sorted(run.cases.items()))}), "
        f"{len(run.failures)} failures, {len(run.errors)} errors, {run.elapsed_s:.0f} s "
        f"({', '.join(f'{p} {s:.0f}' for p, s in run.phase_s.items() if s >= 0.5)}); "
        f"statuses {dict(sorted(run.statuses.items()))}"
    )
    print(f"excused: {dict(EXCUSED_USES)}")
    assert not run.errors, "\n".join(run.errors)
    assert not run.failures, "\n".join(sorted(set(run.failures)))
    if backend == COVERAGE_BACKEND:  # every operation enumerated, none fuzzed
        assert run.operations["coverage"] == documented
        assert run.cases["coverage"] > 10 * len(documented) and run.cases["fuzzing"] == 0
    else:  # every operation fuzzed, none enumerated
        assert run.operations["fuzzing"] == documented
        assert run.cases["fuzzing"] >= len(documented) and run.cases["coverage"] == 0
    # The run reached the routes, not only the edge's refusals: successes and 404s.
    assert run.statuses[200] > 0 and run.statuses[404] > 0


def _case(method: str, path: str, positive: bool) -> Any:
    mode = SimpleNamespace(is_positive=positive)
    return SimpleNamespace(
        method=method, path=path, meta=SimpleNamespace(generation=SimpleNamespace(mode=mode))
    )


def _response(status: int, code: str) -> Any:
    content = json.dumps({"error": {"code": code, "message": "", "detail": None}}).encode()
    return SimpleNamespace(status_code=status, content=content)


def test_an_exclusion_covers_its_codes_only() -> None:
    check = excused_refusals_are_the_documented_ones
    assert check(None, _response(422, "window_reversed"), _case("POST", "/api/passes", True))
    with pytest.raises(AssertionError, match="invalid_request"):
        check(None, _response(422, "invalid_request"), _case("POST", "/api/passes", True))
    with pytest.raises(AssertionError, match="internal_error"):
        check(None, _response(503, "internal_error"), _case("POST", "/api/vehicle/safe-exit", True))
    # a negative case's 422 is the refusal it should get; other statuses are not excused
    assert (
        check(None, _response(422, "invalid_request"), _case("POST", "/api/passes", False)) is None
    )
    assert check(None, _response(404, "not_found"), _case("POST", "/api/passes", True)) is None
    assert (
        check(None, _response(422, "x"), _case("POST", "/api/passes/{pass_id}/start", True)) is None
    )
