"""Mission files: the shipped ETS-VII file loads to the numbers of SPEC section 8, every
fault is refused naming the file, the key and the reason, and a TLE gives the same windows
as the mean elements it was written from."""

from __future__ import annotations

import re
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest
from sgp4 import exporter

from mission import MISSIONS_DIR, InvalidMission, compute_windows, load_mission

ETS7 = MISSIONS_DIR / "ets7-1999.toml"


def test_the_shipped_mission_is_spec_section_8() -> None:
    m = load_mission(ETS7)
    assert m.name == "ets7-1999"
    e = m.orbit.elements
    assert e is not None and m.orbit.tle is None
    assert e.inclination_deg == 35.0 and e.period_min == 95.6 and e.eccentricity < 0.01
    sat = m.orbit.satrec()
    altitude_km = sat.a * sat.radiusearthkm - 6378.137
    assert 540.0 < altitude_km < 560.0  # "about 550 km"
    assert [(r.name, r.longitude_deg) for r in m.relays] == [
        ("TDRS-East", -41.0),
        ("TDRS-West", -174.0),
    ]
    assert m.visibility.grazing_height_km == 100.0
    assert m.orbit.epoch_utc == datetime(1999, 9, 30, tzinfo=UTC)
    assert len(m.content_sha256) == 64


def _write(tmp_path: Path, text: str, name: str = "m.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


BASE = ETS7.read_text()


@pytest.mark.parametrize(
    ("old", "new", "key", "reason"),
    [
        (
            "inclination_deg = 35.0",
            "inclination_deg = 235.0",
            "vehicle.elements.inclination_deg",
            "outside [0, 180]",
        ),
        (
            "period_min = 95.6",
            'period_min = "95.6"',
            "vehicle.elements.period_min",
            "must be a number",
        ),
        ("period_min = 95.6", "perod_min = 95.6", "vehicle.elements", "missing period_min"),
        (
            "eccentricity = 0.0005",
            "eccentricity = 0.0005\ndrag = 1",
            "vehicle.elements",
            "unknown key 'drag'",
        ),
        (
            'epoch = "1999-09-30T00:00:00Z"',
            'epoch = "1999-09-30T00:00:00"',
            "vehicle.elements.epoch",
            "no UTC offset",
        ),
        (
            'epoch = "1999-09-30T00:00:00Z"',
            'epoch = "yesterday"',
            "vehicle.elements.epoch",
            "not an ISO 8601 time",
        ),
        (
            "longitude_deg = -41.0",
            "longitude_deg = 100.0",
            "relays[0].longitude_deg",
            "below the horizon of the ground terminal",
        ),
        ('name = "TDRS-West"', 'name = "TDRS-East"', "relays[1].name", "named twice"),
        ('name = "TDRS-West"', 'name = "TDRS West!"', "relays[1].name", "is not a name"),
        (
            "processing_delay_s = 2.75",
            "processing_delay_s = -1",
            "ground.processing_delay_s",
            "outside [0, 60]",
        ),
        (
            "grazing_height_km = 100.0",
            "grazing_height_km = nan",
            "visibility.grazing_height_km",
            "must be finite",
        ),
        ("aos_margin_s = 120.0", "aos_margn_s = 120.0", "pass", "unknown key 'aos_margn_s'"),
        ("period_min = 95.6", "period_min = 86.0\n", "vehicle", "perigee at"),
        (
            "[vehicle.elements]",
            '[vehicle.tle]\nline1 = "x"\nline2 = "y"\n[vehicle.elements]',
            "vehicle",
            "exactly one of",
        ),
    ],
)
def test_faults_name_the_file_the_key_and_the_reason(
    tmp_path: Path, old: str, new: str, key: str, reason: str
) -> None:
    assert old in BASE
    path = _write(tmp_path, BASE.replace(old, new, 1))
    with pytest.raises(InvalidMission) as caught:
        load_mission(path)
    assert caught.value.key == key, str(caught.value)
    assert reason in caught.value.reason, str(caught.value)
    assert str(caught.value).startswith(f"{path}: {key}: ")


def test_a_shipped_mission_by_its_name(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)  # no file of that name here: the name is the shipped mission's
    assert load_mission("ets7-1999") == load_mission(ETS7)
    with pytest.raises(InvalidMission, match=r"nor a shipped mission \(ets7-1999\)"):
        load_mission("ets7-2000")


def test_files_that_are_not_missions(tmp_path: Path) -> None:
    with pytest.raises(InvalidMission, match="no such file"):
        load_mission(tmp_path / "absent.toml")
    with pytest.raises(InvalidMission, match="not valid TOML"):
        load_mission(_write(tmp_path, "[mission\n"))
    with pytest.raises(InvalidMission, match="missing ground, mission, relays, vehicle"):
        load_mission(_write(tmp_path, "x = 1\n"))
    with pytest.raises(InvalidMission, match="over the 262144 limit"):
        load_mission(_write(tmp_path, "#" * 300_000))
    with pytest.raises(InvalidMission, match="is not a mission name"):
        load_mission(_write(tmp_path, BASE, name="bad name.toml"))


def _tle_mission(tmp_path: Path, line1: str, line2: str) -> Path:
    text = re.sub(
        r"\[vehicle\.elements\].*?(?=\n# TDRS)",
        f'[vehicle.tle]\nline1 = "{line1}"\nline2 = "{line2}"\n',
        BASE,
        flags=re.S,
    )
    return _write(tmp_path, text)


def test_a_tle_gives_the_windows_of_its_elements(tmp_path: Path) -> None:
    elements = load_mission(ETS7)
    line1, line2 = exporter.export_tle(elements.orbit.satrec())
    from_tle = load_mission(_tle_mission(tmp_path, line1, line2))
    assert from_tle.orbit.tle == (line1, line2)
    assert from_tle.orbit.epoch_utc == elements.orbit.epoch_utc
    start = datetime(1999, 9, 30, tzinfo=UTC)
    a = compute_windows(elements, start, 6.0)
    b = compute_windows(from_tle, start, 6.0)
    assert len(a) == len(b) >= 6
    for wa, wb in zip(a, b, strict=True):
        # The TLE rounds the elements (mean anomaly to 1e-4 deg, 0.002 s of the orbit).
        assert wa.relay == wb.relay
        assert abs((wa.aos_utc - wb.aos_utc).total_seconds()) < 0.5
        assert abs((wa.los_utc - wb.los_utc).total_seconds()) < 0.5
    # A corrupted checksum is refused.
    bad = line2[:68] + str((int(line2[68]) + 1) % 10)
    with pytest.raises(InvalidMission, match=r"vehicle\.tle\.line2: checksum"):
        load_mission(_tle_mission(tmp_path, line1, bad))


def test_a_window_does_not_depend_on_the_span_that_found_it() -> None:
    m = load_mission(ETS7)
    day = compute_windows(m, datetime(1999, 9, 30, tzinfo=UTC), 24.0)
    for w in (day[0], day[13], day[-1]):
        around = compute_windows(m, w.aos_utc - timedelta(seconds=90), 0.05)
        assert [x for x in around if x.relay == w.relay] == [w]
