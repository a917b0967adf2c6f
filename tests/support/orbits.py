"""The shipped mission's vehicle read independently of mission/: its file as TOML, its
orbit through sgp4's own initialiser."""

from __future__ import annotations

import math
import tomllib
from datetime import datetime
from typing import Any

from sgp4.api import WGS72, Satrec, jday

from mission import MISSIONS_DIR

#: The shipped mission.
ETS7 = MISSIONS_DIR / "ets7-1999.toml"


def mission_doc() -> dict[str, Any]:
    """The shipped mission file, as TOML."""
    return tomllib.loads(ETS7.read_text())


def satrec(doc: dict[str, Any]) -> Satrec:
    """The file's mean elements through sgp4's own initialiser."""
    e = doc["vehicle"]["elements"]
    epoch = datetime.fromisoformat(e["epoch"])
    jd, fr = jday(epoch.year, epoch.month, epoch.day, epoch.hour, epoch.minute, epoch.second)
    sat = Satrec()
    sat.sgp4init(
        WGS72,
        "i",
        1,
        jd + fr - 2433281.5,
        e.get("bstar_per_earth_radius", 0.0),
        0.0,
        0.0,
        e["eccentricity"],
        math.radians(e["argument_of_perigee_deg"]),
        math.radians(e["inclination_deg"]),
        math.radians(e["mean_anomaly_deg"]),
        2.0 * math.pi / e["period_min"],
        math.radians(e["raan_deg"]),
    )
    return sat
