"""Mission files: a vehicle's orbit, the relays it talks through, the ground and the rules
of a contact window, read from TOML and checked (format: docs/missions.md).

    load_mission(path) -> Mission      read, parse, check; InvalidMission on any fault

The orbit is a two-line element set (``[vehicle.tle]``) or mean elements with an epoch
(``[vehicle.elements]``), either turned into an ``sgp4`` satellite record here, so that a
file whose elements SGP4 refuses is refused on load. Relays are geostationary, given by
their longitude. Every fault names the file, the key and the reason; unknown keys are
faults too (a misspelt margin must not fall back silently to a default).
"""

from __future__ import annotations

import hashlib
import math
import re
import tomllib
from collections.abc import Mapping
from collections.abc import Set as AbstractSet
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from sgp4.api import WGS72, Satrec

from mission.errors import InvalidMission
from mission.shipped import mission_file

__all__ = [
    "EARTH_MU_KM3PS2",
    "GEO_RADIUS_KM",
    "MAX_FILE_BYTES",
    "MISSIONS_DIR",
    "NAME",
    "GroundStation",
    "Margins",
    "MeanElements",
    "Mission",
    "Orbit",
    "Relay",
    "Terminal",
    "Visibility",
    "load_mission",
]

#: A mission file is refused by its size before it is read.
MAX_FILE_BYTES = 256 * 1024
#: The shipped missions: in an installed wheel beside this package (``missions``, setup.py
#: copies them there), else the checkout's ``examples/missions`` (an editable install).
_PACKAGED = Path(__file__).resolve().parent / "missions"
MISSIONS_DIR = (
    _PACKAGED
    if _PACKAGED.is_dir()
    else Path(__file__).resolve().parents[1] / "examples" / "missions"
)
#: A mission's, a relay's or a station's name: what a request may use to name it.
NAME = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")
#: WGS-72's gravitational parameter, the one SGP4 uses (period <-> semi-major axis).
EARTH_MU_KM3PS2 = 398600.8
#: The geostationary radius, (GM T^2 / 4 pi^2)^(1/3) with WGS-84's GM = 398600.4418 km^3/s^2
#: and the sidereal day T = 86164.0905 s.
GEO_RADIUS_KM = 42164.17
#: Julian date of SGP4's epoch origin, 1949 December 31 00:00 UT.
_SGP4_EPOCH0_JD = 2433281.5
_UNIX_EPOCH_JD = 2440587.5


@dataclass(frozen=True)
class MeanElements:
    """SGP4 mean elements at an epoch (a TLE's numbers, in named units)."""

    epoch_utc: datetime
    period_min: float  # from the mean motion, as a TLE's (Kozai) mean motion gives it
    inclination_deg: float
    eccentricity: float
    raan_deg: float
    argument_of_perigee_deg: float
    mean_anomaly_deg: float
    bstar_per_earth_radius: float


@dataclass(frozen=True)
class Orbit:
    """The vehicle's orbit: a TLE or mean elements, and its SGP4 record (built once)."""

    tle: tuple[str, str] | None
    elements: MeanElements | None
    epoch_utc: datetime

    def satrec(self) -> Satrec:
        """A fresh ``sgp4`` satellite record of this orbit."""
        if self.tle is not None:
            return Satrec.twoline2rv(*self.tle)
        assert self.elements is not None
        return _satrec_of(self.elements)


@dataclass(frozen=True)
class Relay:
    """A geostationary relay: its name in requests, the satellite, its longitude."""

    name: str
    satellite: str
    longitude_deg: float  # east positive

    def position_itrs_km(self) -> tuple[float, float, float]:
        lon = math.radians(self.longitude_deg)
        return (GEO_RADIUS_KM * math.cos(lon), GEO_RADIUS_KM * math.sin(lon), 0.0)


@dataclass(frozen=True)
class Terminal:
    """The relays' ground terminal (where the relay's link comes down)."""

    name: str
    latitude_deg: float
    longitude_deg: float
    altitude_m: float


@dataclass(frozen=True)
class GroundStation:
    """The operations station and the link's fixed ground-processing delay (one way)."""

    station: str
    latitude_deg: float
    longitude_deg: float
    processing_delay_s: float
    terminal: Terminal


@dataclass(frozen=True)
class Visibility:
    """A relay is visible when the line of sight clears a sphere of ``earth_radius_km`` by
    ``grazing_height_km``."""

    earth_radius_km: float
    grazing_height_km: float

    @property
    def clearance_radius_km(self) -> float:
        return self.earth_radius_km + self.grazing_height_km


@dataclass(frozen=True)
class Margins:
    """What a pass keeps free after acquisition and before loss of signal."""

    aos_margin_s: float
    los_margin_s: float


@dataclass(frozen=True)
class Mission:
    """A loaded, checked mission file."""

    name: str  # the file's stem
    path: Path
    content_sha256: str
    description: str
    vehicle: str
    orbit: Orbit
    relays: tuple[Relay, ...]
    ground: GroundStation
    visibility: Visibility
    margins: Margins

    def relay(self, name: str) -> Relay:
        for relay in self.relays:
            if relay.name == name:
                return relay
        known = ", ".join(r.name for r in self.relays)
        raise KeyError(f"mission {self.name} has no relay {name!r} (it has {known})")


def load_mission(path: Path | str) -> Mission:
    """The mission file at ``path`` (or the shipped mission it names: ``ets7-1999``), read
    and checked; :class:`InvalidMission` on any fault."""
    path = mission_file(path, MISSIONS_DIR)
    raw = _read_limited(path)
    try:
        doc = tomllib.loads(raw.decode("utf-8"))
    except UnicodeDecodeError:
        raise InvalidMission(path, "document", "not UTF-8 text") from None
    except tomllib.TOMLDecodeError as exc:
        raise InvalidMission(path, "document", f"not valid TOML: {exc}") from None
    name = path.stem
    if not NAME.match(name):
        raise InvalidMission(path, "file name", f"{name!r} is not a mission name ({NAME.pattern})")
    c = _Checker(path)
    top = c.table(
        "document",
        doc,
        required={"mission", "vehicle", "relays", "ground"},
        optional={"visibility", "pass"},
    )
    mission_t = c.table("mission", top["mission"], required={"description"})
    vehicle_t = c.table("vehicle", top["vehicle"], required={"name"}, optional={"tle", "elements"})
    orbit = _orbit(c, vehicle_t)
    relays = _relays(c, top["relays"])
    ground = _ground(c, top["ground"])
    visibility = _visibility(c, top.get("visibility", {}))
    margins = _margins(c, top.get("pass", {}))
    _terminal_sees_relays(c, ground.terminal, relays, visibility.earth_radius_km)
    _perigee_clears(c, orbit, visibility)
    return Mission(
        name=name,
        path=path,
        content_sha256=hashlib.sha256(raw).hexdigest(),
        description=c.text("mission.description", mission_t["description"], limit=2000),
        vehicle=c.name("vehicle.name", vehicle_t["name"]),
        orbit=orbit,
        relays=relays,
        ground=ground,
        visibility=visibility,
        margins=margins,
    )


def _read_limited(path: Path) -> bytes:
    try:
        size = path.stat().st_size
    except FileNotFoundError:
        raise InvalidMission(path, "file", "no such file") from None
    except OSError as exc:
        raise InvalidMission(path, "file", f"cannot read it: {exc.strerror}") from None
    if not path.is_file():
        raise InvalidMission(path, "file", "not a regular file")
    if size > MAX_FILE_BYTES:
        raise InvalidMission(path, "file", f"{size} bytes, over the {MAX_FILE_BYTES} limit")
    try:
        with path.open("rb") as f:
            data = f.read(MAX_FILE_BYTES + 1)
    except OSError as exc:
        raise InvalidMission(path, "file", f"cannot read it: {exc.strerror}") from None
    if len(data) > MAX_FILE_BYTES:
        raise InvalidMission(path, "file", f"over the {MAX_FILE_BYTES} byte limit")
    return data


class _Checker:
    """Raises :class:`InvalidMission` for one file."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def fail(self, key: str, reason: str) -> InvalidMission:
        return InvalidMission(self.path, key, reason)

    def table(
        self,
        key: str,
        value: object,
        *,
        required: AbstractSet[str] = frozenset(),
        optional: AbstractSet[str] = frozenset(),
    ) -> Mapping[str, Any]:
        if not isinstance(value, dict):
            raise self.fail(key, f"must be a table, got {type(value).__name__}")
        missing = sorted(required - value.keys())
        if missing:
            raise self.fail(key, f"missing {', '.join(missing)}")
        unknown = sorted(value.keys() - required - optional)
        if unknown:
            allowed = ", ".join(sorted(required | optional))
            raise self.fail(key, f"unknown key {unknown[0]!r} (allowed: {allowed})")
        return value

    def number(
        self, key: str, value: object, low: float, high: float, *, open_low: bool = False
    ) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.fail(key, f"must be a number, got {value!r}")
        out = float(value)
        if not math.isfinite(out):
            raise self.fail(key, f"must be finite, got {value!r}")
        if out < low or out > high or (open_low and out == low):
            bracket = "(" if open_low else "["
            raise self.fail(key, f"{out:g} is outside {bracket}{low:g}, {high:g}]")
        return out

    def text(self, key: str, value: object, *, limit: int = 200) -> str:
        if not isinstance(value, str) or not value.strip():
            raise self.fail(key, f"must be a non-empty string, got {value!r}")
        if len(value) > limit:
            raise self.fail(key, f"{len(value)} characters, over the {limit} limit")
        if any(ord(ch) < 32 and ch not in "\n\t" for ch in value):
            raise self.fail(key, "has control characters")
        return value

    def name(self, key: str, value: object) -> str:
        if not isinstance(value, str) or not NAME.match(value):
            raise self.fail(key, f"{value!r} is not a name (letters, digits, _ . -; 1-64)")
        return value

    def utc(self, key: str, value: object) -> datetime:
        if isinstance(value, datetime):
            moment = value
        elif isinstance(value, str):
            try:
                moment = datetime.fromisoformat(value)
            except ValueError:
                raise self.fail(key, f"{value!r} is not an ISO 8601 time") from None
        else:
            raise self.fail(key, f"must be an ISO 8601 time with its offset, got {value!r}")
        if moment.tzinfo is None:
            raise self.fail(key, f"{value!r} has no UTC offset (write e.g. ...T00:00:00Z)")
        return moment.astimezone(UTC)


def _orbit(c: _Checker, vehicle: Mapping[str, Any]) -> Orbit:
    has_tle, has_elements = "tle" in vehicle, "elements" in vehicle
    if has_tle == has_elements:
        raise c.fail("vehicle", "give exactly one of [vehicle.tle] and [vehicle.elements]")
    if has_tle:
        t = c.table("vehicle.tle", vehicle["tle"], required={"line1", "line2"})
        line1 = _tle_line(c, "vehicle.tle.line1", t["line1"], "1")
        line2 = _tle_line(c, "vehicle.tle.line2", t["line2"], "2")
        if line1[2:7] != line2[2:7]:
            raise c.fail("vehicle.tle", "the two lines name different satellite numbers")
        sat = Satrec.twoline2rv(line1, line2)
        _check_propagates(c, "vehicle.tle", sat)
        epoch = _utc_of_jd(sat.jdsatepoch, sat.jdsatepochF)
        return Orbit(tle=(line1, line2), elements=None, epoch_utc=epoch)
    k = "vehicle.elements"
    t = c.table(
        k,
        vehicle["elements"],
        required={
            "epoch",
            "period_min",
            "inclination_deg",
            "eccentricity",
            "raan_deg",
            "argument_of_perigee_deg",
            "mean_anomaly_deg",
        },
        optional={"bstar_per_earth_radius"},
    )
    elements = MeanElements(
        epoch_utc=c.utc(f"{k}.epoch", t["epoch"]),
        period_min=c.number(f"{k}.period_min", t["period_min"], 85.0, 1500.0),
        inclination_deg=c.number(f"{k}.inclination_deg", t["inclination_deg"], 0.0, 180.0),
        eccentricity=c.number(f"{k}.eccentricity", t["eccentricity"], 0.0, 0.9),
        raan_deg=c.number(f"{k}.raan_deg", t["raan_deg"], 0.0, 360.0),
        argument_of_perigee_deg=c.number(
            f"{k}.argument_of_perigee_deg", t["argument_of_perigee_deg"], 0.0, 360.0
        ),
        mean_anomaly_deg=c.number(f"{k}.mean_anomaly_deg", t["mean_anomaly_deg"], 0.0, 360.0),
        bstar_per_earth_radius=c.number(
            f"{k}.bstar_per_earth_radius", t.get("bstar_per_earth_radius", 0.0), -1.0, 1.0
        ),
    )
    if not 1957 <= elements.epoch_utc.year <= 2056:
        raise c.fail(f"{k}.epoch", f"year {elements.epoch_utc.year} outside SGP4's 1957-2056")
    _check_propagates(c, k, _satrec_of(elements))
    return Orbit(tle=None, elements=elements, epoch_utc=elements.epoch_utc)


def _tle_line(c: _Checker, key: str, value: object, number: str) -> str:
    if not isinstance(value, str):
        raise c.fail(key, f"must be a string, got {value!r}")
    line = value.rstrip()
    if len(line) != 69 or not line.startswith(number + " "):
        raise c.fail(key, f"not TLE line {number} (69 characters starting {number!r})")
    digits = sum(int(ch) if ch.isdigit() else (1 if ch == "-" else 0) for ch in line[:68])
    if not line[68].isdigit() or digits % 10 != int(line[68]):
        raise c.fail(key, f"checksum {line[68]!r} does not match the line's ({digits % 10})")
    return line


def _satrec_of(e: MeanElements) -> Satrec:
    jd = e.epoch_utc.timestamp() / 86400.0 + _UNIX_EPOCH_JD
    sat = Satrec()
    sat.sgp4init(
        WGS72,
        "i",
        99999,  # no catalogue number: the elements are ours (docs/missions.md)
        jd - _SGP4_EPOCH0_JD,
        e.bstar_per_earth_radius,
        0.0,
        0.0,
        e.eccentricity,
        math.radians(e.argument_of_perigee_deg),
        math.radians(e.inclination_deg),
        math.radians(e.mean_anomaly_deg),
        2.0 * math.pi / e.period_min,  # rad/min
        math.radians(e.raan_deg),
    )
    return sat


def _check_propagates(c: _Checker, key: str, sat: Satrec) -> None:
    error, _, _ = sat.sgp4(sat.jdsatepoch, sat.jdsatepochF)
    if error != 0:
        raise c.fail(key, f"SGP4 refuses these elements at their epoch (error code {error})")


def _utc_of_jd(jd: float, fraction: float) -> datetime:
    seconds = ((jd - _UNIX_EPOCH_JD) + fraction) * 86400.0
    return datetime.fromtimestamp(round(seconds, 6), tz=UTC)


def _relays(c: _Checker, value: object) -> tuple[Relay, ...]:
    if not isinstance(value, list) or not value:
        raise c.fail("relays", "must be a non-empty array of tables ([[relays]])")
    if len(value) > 16:
        raise c.fail("relays", f"{len(value)} relays, over the limit of 16")
    relays: list[Relay] = []
    for i, item in enumerate(value):
        k = f"relays[{i}]"
        t = c.table(k, item, required={"name", "satellite", "longitude_deg"})
        relay = Relay(
            name=c.name(f"{k}.name", t["name"]),
            satellite=c.text(f"{k}.satellite", t["satellite"]),
            longitude_deg=c.number(f"{k}.longitude_deg", t["longitude_deg"], -180.0, 180.0),
        )
        if any(r.name == relay.name for r in relays):
            raise c.fail(f"{k}.name", f"{relay.name!r} is named twice")
        relays.append(relay)
    return tuple(relays)


def _ground(c: _Checker, value: object) -> GroundStation:
    t = c.table(
        "ground",
        value,
        required={"station", "latitude_deg", "longitude_deg", "processing_delay_s", "terminal"},
    )
    k = "ground.terminal"
    term = c.table(
        k,
        t["terminal"],
        required={"name", "latitude_deg", "longitude_deg"},
        optional={"altitude_m"},
    )
    return GroundStation(
        station=c.text("ground.station", t["station"]),
        latitude_deg=c.number("ground.latitude_deg", t["latitude_deg"], -90.0, 90.0),
        longitude_deg=c.number("ground.longitude_deg", t["longitude_deg"], -180.0, 180.0),
        processing_delay_s=c.number(
            "ground.processing_delay_s", t["processing_delay_s"], 0.0, 60.0
        ),
        terminal=Terminal(
            name=c.text(f"{k}.name", term["name"]),
            latitude_deg=c.number(f"{k}.latitude_deg", term["latitude_deg"], -90.0, 90.0),
            longitude_deg=c.number(f"{k}.longitude_deg", term["longitude_deg"], -180.0, 180.0),
            altitude_m=c.number(f"{k}.altitude_m", term.get("altitude_m", 0.0), -500.0, 9000.0),
        ),
    )


def _visibility(c: _Checker, value: object) -> Visibility:
    t = c.table("visibility", value, optional={"earth_radius_km", "grazing_height_km"})
    return Visibility(
        earth_radius_km=c.number(
            "visibility.earth_radius_km", t.get("earth_radius_km", 6378.137), 6350.0, 6400.0
        ),
        grazing_height_km=c.number(
            "visibility.grazing_height_km", t.get("grazing_height_km", 100.0), 0.0, 2000.0
        ),
    )


def _margins(c: _Checker, value: object) -> Margins:
    t = c.table("pass", value, optional={"aos_margin_s", "los_margin_s"})
    return Margins(
        aos_margin_s=c.number("pass.aos_margin_s", t.get("aos_margin_s", 0.0), 0.0, 3600.0),
        los_margin_s=c.number("pass.los_margin_s", t.get("los_margin_s", 0.0), 0.0, 3600.0),
    )


def _terminal_sees_relays(
    c: _Checker, terminal: Terminal, relays: tuple[Relay, ...], earth_radius_km: float
) -> None:
    """Every relay is above the terminal's horizon (a sphere; the terminal's link is always
    up when it is, so the windows are the vehicle-relay geometry alone)."""
    lat = math.radians(terminal.latitude_deg)
    for i, relay in enumerate(relays):
        dlon = math.radians(relay.longitude_deg - terminal.longitude_deg)
        cos_central = math.cos(lat) * math.cos(dlon)
        if cos_central <= earth_radius_km / GEO_RADIUS_KM:
            raise c.fail(
                f"relays[{i}].longitude_deg",
                f"{relay.name} at {relay.longitude_deg:g} deg is below the horizon of the "
                f"ground terminal {terminal.name}",
            )


def _perigee_clears(c: _Checker, orbit: Orbit, visibility: Visibility) -> None:
    sat = orbit.satrec()
    a_km = sat.a * sat.radiusearthkm
    perigee_km = a_km * (1.0 - sat.ecco) - visibility.earth_radius_km
    if perigee_km < 100.0:
        raise c.fail("vehicle", f"perigee at {perigee_km:.0f} km altitude, under 100 km")
