"""The refusals of the ground's services: what went wrong, never how HTTP says it.

    DomainError               code, message, detail (JSON-able, or None)
    ├── NotFoundError         the thing asked for does not exist (an analysis not run, a
    │                         figure, a robot a stored plan names)
    ├── ConflictError         the request clashes with the state it meets (a pass not
    │                         flown, a robot this server has no description of, the
    │                         vehicle's robot not the plan's, the link down)
    ├── InvalidRequestError   the request is understood but refused (a reversed window,
    │                         an unknown field or robot, a plan that cannot be made, a
    │                         recording that cannot be read)
    ├── UnavailableError      the work cannot be done now: retry after ``retry_after_s``
    ├── DeadlineExceededError the work did not finish within its deadline and was stopped
    ├── ClientGoneError       the client went away; the work was stopped
    └── JobFailedError        a worker job failed unexpectedly

``code`` is the machine-readable reason clients see (``"window_reversed"``), ``message``
names the bad value and what was expected. The API maps each kind to its status in one
place (:mod:`server.api.errors`); the command-line tools print the message. Errors cross
the worker processes' pipe intact (they pickle by their fields, whatever a subclass's
constructor takes).
"""

from __future__ import annotations

from typing import Any

__all__ = [
    "ClientGoneError",
    "ConflictError",
    "DeadlineExceededError",
    "DomainError",
    "InvalidRequestError",
    "JobFailedError",
    "NotFoundError",
    "UnavailableError",
]


def _restore(cls: type[DomainError], state: dict[str, Any]) -> DomainError:
    exc = cls.__new__(cls)
    Exception.__init__(exc, state["message"])
    exc.__dict__.update(state)
    return exc


class DomainError(Exception):
    """A request a service refuses: ``code``, ``message`` and an optional ``detail``."""

    def __init__(self, code: str, message: str, detail: Any = None) -> None:
        super().__init__(message)
        self.code = code
        self.message = message
        self.detail = detail

    def __reduce__(self) -> tuple[Any, ...]:
        return _restore, (type(self), dict(self.__dict__))


class NotFoundError(DomainError):
    """The thing asked for does not exist."""


class ConflictError(DomainError):
    """The request clashes with the state of what it acts on."""


class InvalidRequestError(DomainError):
    """The request is understood but cannot be carried out as asked."""


class UnavailableError(DomainError):
    """The work cannot be done now; the client may retry after ``retry_after_s`` seconds
    (also in ``detail``)."""

    def __init__(self, message: str, retry_after_s: float, code: str = "busy") -> None:
        super().__init__(code, message, {"retry_after_s": retry_after_s})
        self.retry_after_s = retry_after_s


class DeadlineExceededError(DomainError):
    """The work ran past its deadline and was stopped."""


class ClientGoneError(DomainError):
    """The client went away while the work ran; it was stopped."""


class JobFailedError(DomainError):
    """A worker job raised something no service expresses (its traceback is logged)."""
