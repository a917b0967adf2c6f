"""The windows of ETS-VII's 1999 mission recomputed without the code under test: plain
``sgp4`` (its own API, TEME positions), the relays put into TEME with the IAU-82 sidereal
time, and the line-of-sight arithmetic written here. Every acquisition and loss agrees
within 2 s; the windows' durations, ranges and light times are those of a LEO-GEO relay.
"""

from __future__ import annotations

import itertools
import math
from datetime import UTC, datetime, timedelta

import numpy as np
import pytest
from scipy.optimize import brentq
from sgp4.api import jday

from mission import Window, compute_windows, load_mission
from tests.support.orbits import ETS7, mission_doc, satrec

START = datetime(1999, 9, 30, tzinfo=UTC)
C_KMPS = 299792.458
R_GEO_KM = 42164.17
TOLERANCE_S = 2.0


def _gmst82_rad(jd_ut1: float) -> float:
    """Greenwich mean sidereal time, IAU 1982 (UT1 taken as UTC: < 0.9 s, a few km at GEO)."""
    t = (jd_ut1 - 2451545.0) / 36525.0
    seconds = (
        67310.54841 + (876600.0 * 3600.0 + 8640184.812866) * t + 0.093104 * t**2 - 6.2e-6 * t**3
    )
    return math.radians((seconds % 86400.0) / 240.0)


class Independent:
    """Clearance of the vehicle->relay segment over the Earth's centre, in TEME."""

    def __init__(self) -> None:
        doc = mission_doc()
        self.sat = satrec(doc)
        self.radius_km = (
            doc["visibility"]["earth_radius_km"] + doc["visibility"]["grazing_height_km"]
        )
        self.relays = {r["name"]: r["longitude_deg"] for r in doc["relays"]}

    def _jd(self, moment: datetime) -> tuple[float, float]:
        seconds = moment.second + moment.microsecond * 1e-6
        return jday(moment.year, moment.month, moment.day, moment.hour, moment.minute, seconds)

    def positions(self, relay: str, moment: datetime) -> tuple[np.ndarray, np.ndarray]:
        jd, fr = self._jd(moment)
        error, r, _ = self.sat.sgp4(jd, fr)
        assert error == 0
        angle = _gmst82_rad(jd + fr) + math.radians(self.relays[relay])
        relay_km = np.array([R_GEO_KM * math.cos(angle), R_GEO_KM * math.sin(angle), 0.0])
        return np.array(r), relay_km

    def margin_km(self, relay: str, moment: datetime) -> float:
        """Clearance minus the required radius: > 0 visible."""
        p, q = self.positions(relay, moment)
        d = q - p
        s = min(1.0, max(0.0, -float(p @ d) / float(d @ d)))
        return float(np.linalg.norm(p + s * d)) - self.radius_km

    def windows(self, start: datetime, hours: float) -> list[tuple[str, datetime, datetime]]:
        """A 20 s scan, each sign change solved with Brent's method to 1 ms."""
        out: list[tuple[str, datetime, datetime]] = []
        step = timedelta(seconds=20)
        for relay in self.relays:

            def f(seconds: float, relay: str = relay) -> float:
                return self.margin_km(relay, start + timedelta(seconds=seconds))

            grid = np.arange(-2.0 * 5736.0, hours * 3600.0 + 2.0 * 5736.0, step.total_seconds())
            values = [f(s) for s in grid]
            aos: float | None = None
            for a, b, fa, fb in zip(grid[:-1], grid[1:], values[:-1], values[1:], strict=True):
                if (fa > 0) == (fb > 0):
                    continue
                root = brentq(f, a, b, xtol=1e-3)
                if fb > 0:
                    aos = root
                elif aos is not None:
                    if 0.0 <= aos < hours * 3600.0:
                        out.append(
                            (relay, start + timedelta(seconds=aos), start + timedelta(seconds=root))
                        )
                    aos = None
        return sorted(out, key=lambda w: (w[1], w[0]))


@pytest.fixture(scope="module")
def windows_24h() -> list[Window]:
    return compute_windows(load_mission(ETS7), START, 24.0)


@pytest.fixture(scope="module")
def independent() -> Independent:
    return Independent()


def test_every_acquisition_and_loss_agrees_with_plain_sgp4_within_2_s(
    windows_24h: list[Window], independent: Independent
) -> None:
    theirs = independent.windows(START, 24.0)
    assert len(theirs) >= 28  # both relays, once an orbit
    assert [w.relay for w in windows_24h] == [relay for relay, _, _ in theirs]
    for w, (_, aos, los) in zip(windows_24h, theirs, strict=True):
        assert abs((w.aos_utc - aos).total_seconds()) < TOLERANCE_S, (w, aos)
        assert abs((w.los_utc - los).total_seconds()) < TOLERANCE_S, (w, los)


def test_the_line_of_sight_grazes_at_each_acquisition_and_loss(
    windows_24h: list[Window], independent: Independent
) -> None:
    """A second check on all 24 h: just inside each window the relay is visible, just
    outside it is not (±5 s), by the independent arithmetic."""
    five = timedelta(seconds=5)
    for w in windows_24h:
        for inside, outside in (
            (w.aos_utc + five, w.aos_utc - five),
            (w.los_utc - five, w.los_utc + five),
        ):
            assert independent.margin_km(w.relay, inside) > 0.0, (w, inside)
            assert independent.margin_km(w.relay, outside) < 0.0, (w, outside)


def test_ranges_and_light_times_match_the_independent_geometry(
    windows_24h: list[Window], independent: Independent
) -> None:
    for w in windows_24h[:6]:
        samples = [w.aos_utc + (w.los_utc - w.aos_utc) * k / 400 for k in range(401)]
        ranges = []
        for moment in samples:
            p, q = independent.positions(w.relay, moment)
            ranges.append(float(np.linalg.norm(q - p)))
        assert min(ranges) == pytest.approx(w.min_range_km, abs=5.0)
        assert max(ranges) == pytest.approx(w.max_range_km, abs=5.0)


def test_windows_are_those_of_a_leo_to_geo_relay(windows_24h: list[Window]) -> None:
    period_s = 95.6 * 60.0
    r_leo_max = 6378.137 + 560.0
    grazing = 6378.137 + 100.0
    # Nearest: the relay at the zenith; farthest: both ends tangent to the grazing sphere.
    nearest_km = R_GEO_KM - r_leo_max
    farthest_km = math.sqrt(R_GEO_KM**2 - grazing**2) + math.sqrt(r_leo_max**2 - grazing**2)
    per_relay: dict[str, list[Window]] = {}
    for w in windows_24h:
        per_relay.setdefault(w.relay, []).append(w)
        assert START <= w.aos_utc < START + timedelta(hours=24)
        # The Earth hides the relay once an orbit: a window is shorter than an orbit, and
        # longer than half of one at 550 km with a 100 km grazing height.
        assert 0.5 * period_s < w.duration_s < period_s, w
        assert nearest_km < w.min_range_km < w.max_range_km < farthest_km + 1.0, w
        # Each window reaches the grazing geometry at its ends: its longest range is near
        # the tangent-tangent distance.
        assert w.max_range_km > farthest_km - 50.0, w
        assert 0.0 < w.net_s == pytest.approx(w.duration_s - 180.0)
        # One way: vehicle -> relay -> White Sands; the down leg is about 37 000 km.
        assert 0.23 < w.light_time_min_s < w.light_time_max_s < 0.30
        assert (w.light_time_max_s - w.light_time_min_s) * C_KMPS == pytest.approx(
            w.max_range_km - w.min_range_km, rel=1e-9
        )
    assert set(per_relay) == {"TDRS-East", "TDRS-West"}
    for relay_windows in per_relay.values():
        # One window an orbit: 24 h / 95.6 min = 15.06.
        assert 14 <= len(relay_windows) <= 16
        for a, b in itertools.pairwise(relay_windows):
            gap_s = (b.aos_utc - a.los_utc).total_seconds()
            assert 10 * 60.0 < gap_s < period_s, (a, b)
            assert (b.aos_utc - a.aos_utc).total_seconds() == pytest.approx(period_s, rel=0.1)
