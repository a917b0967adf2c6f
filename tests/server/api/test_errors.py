"""The services' refusals carry no status; the API maps them, and the errors of the layers
below, to HTTP in one place (server/api/errors.py), also when a worker job raised them."""

from __future__ import annotations

import asyncio
import pickle
from typing import Any

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from planner.errors import InfeasibleGoal, JointLimitExceeded
from server.api.errors import HttpError, describe, install_error_handlers, status_of
from server.services import errors as refusals
from server.services.errors import ConflictError, DomainError, InvalidRequestError, UnavailableError
from server.services.imports import InvalidRecording
from server.services.recordings import NotFlown
from server.services.workers import WorkerPool
from server.storage.errors import Conflict, InvalidArgument, NotFound

#: Generous: a loaded 2-core machine may be slow.
PATIENCE_S = 60.0


@pytest.mark.parametrize(
    ("error", "status"),
    [
        (refusals.NotFoundError("analysis_not_run", "m"), 404),
        (ConflictError("robot_mismatch", "m", {"x": 1}), 409),
        (InvalidRequestError("window_reversed", "m"), 422),
        (UnavailableError("m", 2.0), 503),
        (refusals.DeadlineExceededError("deadline_exceeded", "m"), 504),
        (refusals.ClientGoneError("client_closed", "m"), 499),
        (refusals.JobFailedError("worker_failed", "m"), 500),
        (NotFlown("m"), 409),
        (InvalidRecording("invalid_recording", "m"), 422),
    ],
)
def test_every_kind_of_refusal_has_its_status(error: DomainError, status: int) -> None:
    assert describe(error) == (status, error.code, "m", error.detail)
    assert status_of(error) == status


def test_the_errors_of_other_layers_keep_their_statuses_and_codes() -> None:
    assert describe(JointLimitExceeded(2, 3.0, 1.5, "rad")) == (
        422,
        "JointLimitExceeded",
        "joint 2 at 3.000 rad exceeds limit 1.500 rad",
        None,
    )
    assert describe(NotFound("pass p")) == (404, "not_found", "pass p", None)
    assert describe(Conflict("stale")) == (409, "conflict", "stale", None)
    assert describe(InvalidArgument("bad")) == (400, "invalid_argument", "bad", None)
    assert describe(HttpError(413, "request_too_large", "big")) == (
        413,
        "request_too_large",
        "big",
        None,
    )
    assert describe(ValueError("ours, unexpected")) is None
    assert status_of(ValueError("ours, unexpected")) == 500


@pytest.mark.parametrize(
    "error",
    [
        UnavailableError("full", 2.5, "worker_crashed"),
        NotFlown("pass p has not started"),
        InvalidRecording("invalid_recording", "not an MCAP file"),
        ConflictError("robot_mismatch", "not ours", {"vehicle": "ab"}),
    ],
)
def test_a_refusal_pickles_whole_whatever_its_constructor_takes(error: DomainError) -> None:
    back = pickle.loads(pickle.dumps(error))
    assert type(back) is type(error)
    assert (back.code, back.message, back.detail, str(back)) == (
        error.code,
        error.message,
        error.detail,
        str(error),
    )
    assert vars(back) == vars(error)


def _refusing_app() -> FastAPI:
    app = FastAPI()
    install_error_handlers(app)

    @app.get("/busy")
    def busy() -> None:
        raise UnavailableError("every worker is busy", 2.5)

    @app.get("/conflict")
    def conflict() -> None:
        raise ConflictError("robot_mismatch", "the vehicle flies another robot", {"a": 1})

    @app.get("/planner")
    def planner() -> None:
        raise InfeasibleGoal("unreachable")

    return app


def test_the_api_answers_refusals_in_the_one_shape() -> None:
    with TestClient(_refusing_app()) as client:
        busy = client.get("/busy")
        assert busy.status_code == 503
        assert busy.headers["Retry-After"] == "3"
        assert busy.headers["content-type"] == "application/problem+json"
        assert busy.json() == {  # RFC 9457, and the shape before it as a member
            "type": "urn:hikoboshi:problem:busy",
            "title": "Service Unavailable",
            "status": 503,
            "detail": "every worker is busy",
            "code": "busy",
            "data": {"retry_after_s": 2.5},
            "error": {
                "code": "busy",
                "message": "every worker is busy",
                "detail": {"retry_after_s": 2.5},
            },
        }
        conflict = client.get("/conflict")
        assert conflict.status_code == 409 and "Retry-After" not in conflict.headers
        assert conflict.json()["error"] == {
            "code": "robot_mismatch",
            "message": "the vehicle flies another robot",
            "detail": {"a": 1},
        }
        planner = client.get("/planner")
        assert planner.status_code == 422
        assert planner.json()["error"]["code"] == "InfeasibleGoal"
        assert "data" not in planner.json()  # nothing carried beside the message
        assert planner.json()["title"] == "Unprocessable Content"
        unknown = client.get("/no-such-route")
        assert unknown.status_code == 404 and unknown.json()["type"].endswith(":not_found")
        assert unknown.headers["content-type"] == "application/problem+json"


# Job functions: module-level, so that the worker can import them.


def _raise(error: BaseException) -> None:
    raise error


def _raise_joint_limit() -> None:
    raise JointLimitExceeded(1, 2.0, 1.0, "rad")


def test_a_jobs_error_reaches_the_server_as_the_api_would_answer_it_in_process() -> None:
    async def scenario() -> list[tuple[type[BaseException], Any]]:
        pool = WorkerPool(workers=1, queue=0, memory_bytes=None)
        caught: list[tuple[type[BaseException], Any]] = []
        try:
            for job, args in (
                (_raise, (NotFlown("pass p has not started"),)),
                (_raise, (NotFound("no pass p"),)),
                (_raise_joint_limit, ()),
                (_raise, (ValueError("a bug"),)),
            ):
                with pytest.raises(Exception) as raised:
                    await pool.run(job, *args, deadline_s=PATIENCE_S, what="a job")
                caught.append((type(raised.value), describe(raised.value)))
        finally:
            await pool.close()
        return caught

    caught = asyncio.run(scenario())
    assert caught == [
        (NotFlown, (409, "pass_not_flown", "pass p has not started", None)),
        (NotFound, (404, "not_found", "no pass p", None)),
        (
            InvalidRequestError,
            (422, "JointLimitExceeded", "joint 1 at 2.000 rad exceeds limit 1.000 rad", None),
        ),
        (
            refusals.JobFailedError,
            (500, "worker_failed", "the job failed: ValueError: a bug", None),
        ),
    ]
