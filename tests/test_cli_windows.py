"""``hikoboshi windows``: the issue's command, its JSON equal to the library's windows, in a
fresh process with every socket refused; bad input refused with status 2 and the reason."""

from __future__ import annotations

import json
from datetime import UTC, datetime
from pathlib import Path

import pytest

from mission import MISSIONS_DIR, compute_windows, load_mission
from tests.support.offline import run_offline

ETS7 = str(MISSIONS_DIR / "ets7-1999.toml")


def test_the_issue_s_command_offline(tmp_path: Path) -> None:
    result = run_offline(
        "windows",
        "--mission",
        ETS7,
        "--start",
        "1999-09-30T00:00:00Z",
        "--hours",
        "24",
        "--json",
        cwd=tmp_path,
    )
    assert result.returncode == 0, result.stderr
    assert list(tmp_path.iterdir()) == []  # nothing downloaded into the working folder
    doc = json.loads(result.stdout)
    assert doc["mission"] == "ets7-1999" and doc["vehicle"] == "ETS-VII"
    assert doc["start_utc"] == "1999-09-30T00:00:00Z" and doc["hours"] == 24.0
    expected = compute_windows(load_mission(ETS7), datetime(1999, 9, 30, tzinfo=UTC), 24.0)
    assert doc["windows"] == [w.to_dict() for w in expected]
    assert {w["relay"] for w in doc["windows"]} == {"TDRS-East", "TDRS-West"}
    first = doc["windows"][0]
    assert set(first) >= {
        "aos_utc",
        "los_utc",
        "duration_s",
        "min_range_km",
        "max_range_km",
        "light_time_min_s",
        "light_time_max_s",
        "net_s",
    }


def test_the_table() -> None:
    result = run_offline(
        "windows", "--mission", ETS7, "--start", "1999-09-30T00:00:00Z", "--hours", "3"
    )
    assert result.returncode == 0, result.stderr
    assert "ETS-VII: 4 windows from 1999-09-30T00:00:00Z, 3 h" in result.stdout
    assert "TDRS-West  09-30  00:25:14  01:22:58" in result.stdout


@pytest.mark.parametrize(
    ("args", "reason"),
    [
        (["--start", "1999-09-30T00:00:00"], "has no UTC offset"),
        (["--start", "soon"], "is not an ISO 8601 time"),
        (["--start", "1999-09-30T00:00:00Z", "--hours", "0"], "--hours 0 is outside (0, 744]"),
        (["--start", "1999-09-30T00:00:00Z", "--hours", "nan"], "--hours nan is outside"),
        (["--start", "2001-01-01T00:00:00Z"], "over the 60 day limit"),
        (["--start", "0001-01-01T00:00:00+05:00"], "outside the years 1 to 9999 in UTC"),
        (["--start", "9999-12-31T23:00:00Z"], "over the 60 day limit"),
    ],
)
def test_bad_input_is_refused_with_the_reason(args: list[str], reason: str) -> None:
    result = run_offline("windows", "--mission", ETS7, *args)
    assert result.returncode == 2
    assert result.stderr.startswith("error: ") and reason in result.stderr, result.stderr
    assert "Traceback" not in result.stderr


def test_a_bad_mission_file_is_refused_with_file_key_and_reason(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text(Path(ETS7).read_text().replace("inclination_deg = 35.0", "inclination_deg = -1"))
    result = run_offline("windows", "--mission", str(bad), "--start", "1999-09-30T00:00:00Z")
    assert result.returncode == 2
    assert f"{bad}: vehicle.elements.inclination_deg: -1 is outside [0, 180]" in result.stderr
