"""The ground service's settings: passed to :func:`server.app.create_app`, never global.

:meth:`Settings.from_env` is called only by the command line; tests build ``Settings``
directly.
"""

from __future__ import annotations

import os
from enum import StrEnum
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field

__all__ = ["ApiToken", "Role", "Settings"]


class Role(StrEnum):
    VIEWER = "viewer"  # read everything
    OPERATOR = "operator"  # viewer + plan and command
    SPACECRAFT = "spacecraft"  # the link endpoint only


class ApiToken(BaseModel):
    model_config = ConfigDict(frozen=True)
    name: str  # who holds it: written to the audit log
    role: Role


class Settings(BaseModel):
    model_config = ConfigDict(frozen=True)

    data_dir: Path = Path("data")
    #: SQLite under ``data_dir`` unless a URL is given (``postgresql://...``).
    database_url: str | None = None
    #: token -> holder and role
    tokens: dict[str, ApiToken] = Field(default_factory=dict)
    #: SPEC 6: the ground sends each command at least (one-way delay + margin) before its tag
    link_one_way_delay_s: float = 3.0
    uplink_margin_s: float = 2.0
    #: The onboard schedule is kept loaded this far ahead of the onboard clock (onboard s):
    #: every command goes up this long before its tag, and is sent again until
    #: the vehicle acknowledges it, within the vehicle's announced schedule capacity.
    #: Longer than the outages a pass must ride through (SPEC 6).
    uplink_lead_window_s: float = Field(default=120.0, gt=0, le=3600)
    #: A pass's first command is tagged this long (onboard s) after the start, so that it
    #: too can be sent again before its tag if the relay loses it (the runner lengthens it
    #: at high time scales, so that the first command can go up three times).
    uplink_start_lead_s: float = Field(default=30.0, ge=0, le=600)
    command_period_s: float = 0.25
    #: The largest MCAP recording ``POST /api/passes/import`` accepts (the 20-minute demo
    #: pass is 14 MB).
    max_import_bytes: int = 256 * 1024 * 1024

    def resolved_database_url(self) -> str:
        from server.storage.db import sqlite_url

        return self.database_url or sqlite_url(self.data_dir)

    @classmethod
    def from_env(cls) -> Settings:
        """``DATABASE_URL``, ``HIKOBOSHI_DATA_DIR``, ``HIKOBOSHI_TOKENS``
        (``token=name:role,...``) and ``HIKOBOSHI_UPLINK_LEAD_WINDOW_S`` (onboard s)."""
        tokens: dict[str, ApiToken] = {}
        for item in filter(None, os.environ.get("HIKOBOSHI_TOKENS", "").split(",")):
            token, _, holder = item.partition("=")
            name, _, role = holder.partition(":")
            tokens[token.strip()] = ApiToken(name=name.strip(), role=Role(role.strip()))
        lead = os.environ.get("HIKOBOSHI_UPLINK_LEAD_WINDOW_S")
        return cls(
            data_dir=Path(os.environ.get("HIKOBOSHI_DATA_DIR", "data")),
            database_url=os.environ.get("DATABASE_URL") or None,
            tokens=tokens,
            uplink_lead_window_s=float(lead)
            if lead
            else cls.model_fields["uplink_lead_window_s"].default,
        )
