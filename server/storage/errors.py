"""Errors of the storage layer.

    StorageError
    ├── NotFound          a plan, pass, command or analysis that is not stored
    ├── Conflict          the row moved on: an optimistic-lock version mismatch, or a key
    │                     that is already taken
    │   └── LeaseLost     a write of the command path from a ground that no longer holds
    │                     the vehicle's command lease (its fencing token is stale)
    └── InvalidArgument   a value the storage refuses: a telemetry field off the whitelist,
                          an empty or reversed time range, an unknown pass state or command
                          stage, a JSON document holding NaN or infinity

Messages name the bad value and what was expected. After any of these is raised from a
write, the session's transaction must be rolled back by its owner (the service), as after
any database error: a repository function never commits and never rolls back.
"""

from __future__ import annotations

__all__ = ["Conflict", "InvalidArgument", "LeaseLost", "NotFound", "StorageError"]


class StorageError(Exception):
    """Root of every error the storage layer raises."""


class NotFound(StorageError, LookupError):
    """The row asked for is not stored."""


class Conflict(StorageError):
    """The row changed under the caller (stale version) or its key is already taken."""


class LeaseLost(Conflict):
    """The command lease is not this ground's (any more): its write is refused, not applied."""


class InvalidArgument(StorageError, ValueError):
    """An argument the storage refuses (checked before it reaches SQL where it can be)."""
