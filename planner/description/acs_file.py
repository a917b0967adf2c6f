"""An attitude-control law's file: one ``[acs]`` table (``hikoboshi calibrate`` writes one;
``hikoboshi spacecraft --acs-config`` reads it). The table's meaning is
:func:`planner.attitude_control.acs_gains_from_config`'s; this module only reads the file."""

from __future__ import annotations

import tomllib
from pathlib import Path

from planner.attitude_control import AcsGains, acs_gains_from_config
from planner.dynamics import DynamicsWorkspace
from planner.errors import InvalidInput

__all__ = ["load_acs_config"]


def load_acs_config(ws: DynamicsWorkspace, path: str | Path) -> AcsGains:
    """The law from a TOML file: its ``[acs]`` table
    (:func:`planner.attitude_control.acs_gains_from_config`)."""
    try:
        with open(path, "rb") as f:
            doc = tomllib.load(f)
    except tomllib.TOMLDecodeError as exc:
        raise InvalidInput(f"{path}: not valid TOML: {exc}") from None
    except OSError as exc:
        raise InvalidInput(
            f"{path}: cannot read the attitude-control configuration: {exc}"
        ) from None
    unknown = sorted(set(doc) - {"acs"})
    if unknown or not isinstance(doc.get("acs"), dict):
        raise InvalidInput(f"{path}: expected one [acs] table (found {sorted(doc)})")
    try:
        return acs_gains_from_config(ws, doc["acs"])
    except InvalidInput as exc:
        raise InvalidInput(f"{path}: {exc}") from None
