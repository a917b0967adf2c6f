"""What this ground is, for the consoles' link status, ``GET /api/link/status`` and
``/metrics``: whether it commands the vehicle (the command lease,
:mod:`server.services.authority`) and whether its database answers (the command path's
journal during an outage, :mod:`server.services.dbworker`)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from server.services.authority import CommandAuthority
from server.services.dbworker import Database

__all__ = ["ground_status"]


def ground_status(authority: CommandAuthority, db: Database) -> Callable[[], dict[str, Any]]:
    """The status's provider: ``{"command": {...}, "database": {...}}``."""

    def status() -> dict[str, Any]:
        return {
            "command": authority.status(),
            "database": db.outage.status(db.journal),
        }

    return status
