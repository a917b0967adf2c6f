"""What the REST API reads and writes (pydantic): ``XCreate`` in, ``XPublic`` out,
``XsPublic(data, count)`` for a page of a listing.

Times: ground times are ISO-8601 UTC (``created_at``, ``aos_time``); onboard times, which
the spacecraft stamps, are integer ns (``execute_time_ns``) with an ISO rendering beside
them where a client plots them. Tables live apart, in :mod:`server.storage.models`.

Text a client sends is typed so that the OpenAPI document states the edge's rule
(server/api/edge.py, docs/security.md): :data:`SafeText` for strings of a JSON body (no C0
control character but tab, newline and carriage return, no DEL), :data:`SafeLine` for path
and query parameters (no C0 control character at all, no DEL), each with the ``maxLength``
the server enforces where it is used. The patterns are written for ECMA-262 and Python alike
(``\\xHH`` escapes and one character class), so a JSON Schema validator, schemathesis's
generator and pydantic read them the same.

The models live by the API's areas: :mod:`server.schemas.plans` (plans, flight rules,
robots), :mod:`server.schemas.passes` (passes, their summary, contact windows, missions),
:mod:`server.schemas.telemetry` (telemetry, the audit log's events),
:mod:`server.schemas.alarms` and :mod:`server.schemas.analyses` (analyses, reports, imports).
This module holds what they share (times, the text rules, names, the stage and state
literals, :class:`FromRecord`), the one error shape and the commands: their reply's
OpenAPI name, ``server__schemas__CommandPublic`` (``server.api.ready`` has a
``CommandPublic`` of its own), is taken from the module that defines it.
"""

from __future__ import annotations

import re
import unicodedata
from datetime import UTC, datetime, timedelta
from typing import Annotated, Any, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, StringConstraints

__all__ = [
    "EARLIEST",
    "ERROR_RESPONSES",
    "LATEST",
    "LINE_PATTERN",
    "MAX_NS",
    "NAME_PATTERN",
    "NAME_RULE",
    "NAME_TEXT_PATTERN",
    "TEXT_PATTERN",
    "CommandKind",
    "CommandPublic",
    "CommandStage",
    "CommandsPublic",
    "DisplayName",
    "ErrorDetail",
    "ErrorPublic",
    "EventKind",
    "FromRecord",
    "Name",
    "PassState",
    "SafeLine",
    "SafeText",
    "checked_name",
    "iso_from_ns",
    "name_problem",
    "ns_from_datetime",
]

_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)
#: Ground times a client may give: int64 ns reach 2262; keep well inside.
EARLIEST = datetime(1970, 1, 1, tzinfo=UTC)
LATEST = datetime(2200, 1, 1, tzinfo=UTC)
#: The largest int64, the upper bound of every ``*_ns`` a client may give.
MAX_NS = 2**63 - 1

#: A JSON body's strings (and keys): any character but the C0 controls other than tab (09),
#: newline (0A) and carriage return (0D), and DEL (7F). The edge refuses the others, and
#: lone surrogates (which no UTF-8 encoder produces), 400 ``invalid_text``.
TEXT_PATTERN = r"^[^\x00-\x08\x0b\x0c\x0e-\x1f\x7f]*$"
#: A path or query parameter: no C0 control character at all, and no DEL.
LINE_PATTERN = r"^[^\x00-\x1f\x7f]*$"
#: Free text in a JSON body; give it its ``max_length`` where it is used.
SafeText = Annotated[str, StringConstraints(pattern=TEXT_PATTERN)]
#: Free text in a path or query parameter; give it its ``max_length`` where it is used.
SafeLine = Annotated[str, StringConstraints(pattern=LINE_PATTERN)]
#: A name an operator reads and types back (a pass's, a plan's label): beyond TEXT_PATTERN's
#: rule, no control character at all (C0, DEL, C1), no bidi control (they reorder what is
#: shown: a confirmation could read as another pass's name), no zero-width or other invisible
#: format character, no line or paragraph separator, no noncharacter of the Basic Multilingual
#: Plane (those beyond it, and the tag characters of emoji flags, an ECMA pattern without the
#: ``u`` flag cannot name: the OpenAPI document and the server keep the same rule).
#: :func:`name_problem` checks it and says which character it found.
NAME_TEXT_PATTERN = (
    r"^[^\x00-\x1f\x7f-\x9f\u061c\u200b-\u200f\u2028-\u202e\u2060-\u206f\ufdd0-\ufdef"
    r"\ufeff\ufff9-\ufffb\ufffe\uffff]*$"
)
_NAME_CHAR = re.compile(NAME_TEXT_PATTERN)


def name_problem(text: str) -> str | None:
    """Why ``text`` cannot be a name (:data:`NAME_TEXT_PATTERN`), or None: the first
    character refused, by code point and Unicode name."""
    for i, char in enumerate(text, start=1):
        if _NAME_CHAR.fullmatch(char):
            continue
        point = ord(char)
        kind = {
            "Cc": "a control character",
            "Cn": "a noncharacter",
            "Zl": "a line separator",
            "Zp": "a paragraph separator",
        }.get(unicodedata.category(char), "an invisible format character")
        named = unicodedata.name(char, "")
        return (
            f"character {i} is U+{point:04X}{f' {named}' if named else ''}, {kind}: a name may "
            "hold no control, bidi-control, zero-width, separator or noncharacter code point"
        )
    return None


def checked_name(text: str) -> str:
    """``text``, if it can be a name; else ValueError (a validator's refusal) saying why."""
    problem = name_problem(text)
    if problem is not None:
        raise ValueError(problem)
    return text


#: The name rule's parts, after a string's own constraints: the check, and its pattern stated
#: in the OpenAPI document.
NAME_RULE = (AfterValidator(checked_name), Field(json_schema_extra={"pattern": NAME_TEXT_PATTERN}))
#: A name's type in a request body (:data:`NAME_TEXT_PATTERN`; its length where it is used).
DisplayName = Annotated[str, NAME_RULE[0], NAME_RULE[1]]
#: A mission's or a relay's name (``mission.file.NAME``): a request names one, never a file.
NAME_PATTERN = r"^[A-Za-z0-9_.\-]+$"
Name = Annotated[str, StringConstraints(pattern=NAME_PATTERN, min_length=1, max_length=64)]

PassState = Literal["scheduled", "aos", "running", "los", "complete", "aborted", "safed"]
CommandStage = Literal[
    "queued", "released", "sent", "received", "executed", "rejected", "expired", "cancelled"
]
#: What a command moves (server/storage/models.py ``COMMAND_KINDS``).
CommandKind = Literal["joints", "acs"]
#: An audit-log event's kind as a filter: a snake_case name (server/services/events.py).
EventKind = Annotated[str, StringConstraints(pattern=r"^[a-z][a-z0-9_]*$", max_length=64)]


def iso_from_ns(time_ns: int) -> datetime:
    """A UTC datetime (microsecond resolution) for ns since the Unix epoch."""
    return _EPOCH + timedelta(microseconds=time_ns // 1000)


def ns_from_datetime(value: datetime) -> int:
    """ns since the Unix epoch for an aware datetime, exactly."""
    return (value - _EPOCH) // timedelta(microseconds=1) * 1000


class FromRecord(BaseModel):
    """A reply read from a stored record's attributes (``model_validate(record)``)."""

    model_config = ConfigDict(from_attributes=True)


# --- commands ------------------------------------------------------------------------------


class CommandPublic(BaseModel):
    """A command and when it reached each stage: ground stages (``queued`` ... ``sent``,
    ``expired``, ``cancelled``) as ISO-8601 UTC, onboard stages (``received``,
    ``executed``, ``rejected``) as ns on the onboard clock; ``transmissions``, how many
    times it went up (the uplink retransmits until the vehicle acknowledges)."""

    seq: int
    kind: str
    execute_time_ns: int
    payload: dict[str, Any]
    stage: str
    reject_reason: str | None
    queued_at: datetime
    released_at: datetime | None
    sent_at: datetime | None
    expired_at: datetime | None
    cancelled_at: datetime | None
    transmissions: int
    received_at_ns: int | None
    executed_at_ns: int | None
    rejected_at_ns: int | None


class CommandsPublic(BaseModel):
    data: list[CommandPublic]
    count: int


# --- errors --------------------------------------------------------------------------------


class ErrorDetail(BaseModel):
    """The error shape before problem details: the code, the message and what it carries."""

    code: str
    message: str
    detail: Any = None


class ErrorPublic(BaseModel):
    """The one error shape: problem details (RFC 9457, ``application/problem+json``) with the
    code as an extension member (:mod:`server.api.errors`)."""

    type: str = Field(description="urn:hikoboshi:problem: and the code")
    title: str = Field(description="The HTTP status's phrase")
    status: int
    detail: str = Field(description="What went wrong, for a person")
    code: str = Field(description="The machine-readable reason (not_found, window_reversed...)")
    data: Any = Field(default=None, description="What the refusal carries beside its message")
    error: ErrorDetail = Field(
        description="The shape before problem details (code, message, detail), kept for the "
        "clients written against it"
    )


#: Documented on every router, so the OpenAPI document describes the replies clients get.
ERROR_RESPONSES: dict[int | str, dict[str, Any]] = {
    status: {"model": ErrorPublic, "description": description}
    for status, description in (
        (400, "Invalid argument"),
        (401, "No or unknown API token"),
        (403, "The token's role may not do this"),
        (404, "Not found"),
        (409, "Conflict"),
        (413, "The request body exceeds the size limit"),
        (422, "Invalid request, or a plan that cannot be made"),
        (
            429,
            "Too many failed authentications from this address, or too many heavy reads of"
            " this token in flight (Retry-After)",
        ),
        (
            503,
            "Busy: the viewers' share of requests in flight, the bounded work pool, the"
            " readers' database connections or a deadline (Retry-After)",
        ),
        (504, "The work did not finish within its deadline"),
    )
}
