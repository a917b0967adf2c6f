"""``hikoboshi model limits``: the robot's bands, and a nominal ETS-VII PTP flown offline (the
vehicle, its sensor noise, the commands uplinked as the ground does) that stays below every
quantity's lowest band: the defaults never fire in a nominal pass."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from typing import Any

import pytest

from planner.description import EXAMPLES_DIR, default_robot, load_robot
from planner.limits import QUANTITIES
from spacecraft.nominal_limits import LinkNominal, QuantityRow, link_nominal

HIKOBOSHI = [sys.executable, "-m", "hikoboshi"]


def run(*args: str) -> subprocess.CompletedProcess[str]:
    # a guard against a hang, not a timing assertion
    return subprocess.run([*HIKOBOSHI, *args], capture_output=True, text=True, timeout=300)


def test_the_table_is_the_description_s_limits() -> None:
    orihime = EXAMPLES_DIR / "orihime" / "orihime.toml"
    result = run("model", "limits", "--robot", str(orihime), "--json")
    assert result.returncode == 0, result.stderr
    doc = json.loads(result.stdout)
    assert doc["robot"] == "orihime" and doc["seeds"] == []
    assert [q["quantity"] for q in doc["quantities"]] == list(QUANTITIES)
    assert {q["quantity"]: q["bands"] for q in doc["quantities"]} == (
        load_robot(orihime).limits.to_table()
    )
    assert all(q["nominal"] is None for q in doc["quantities"])
    text = run("model", "limits")
    assert text.returncode == 0, text.stderr
    assert "critical* 3" in text.stdout and "joint_tracking_error_deg" in text.stdout


@pytest.mark.parametrize(
    ("args", "reason"),
    [
        (("--fly", "--seeds", "one"), "--seeds 'one'"),
        (("--robot", "nowhere.toml"), "nowhere.toml"),
        (("--fly", "--experiment", "juggling", "--seeds", "1"), "unknown experiment"),
    ],
)
def test_bad_input_is_one_line_and_status_2(args: tuple[str, ...], reason: str) -> None:
    result = run("model", "limits", *args)
    assert result.returncode == 2
    assert reason in result.stderr and "Traceback" not in result.stderr


@pytest.mark.slow
def test_a_nominal_ptp_stays_below_every_band() -> None:
    result = run("model", "limits", "--fly", "--experiment", "ptp", "--seeds", "3", "--json")
    assert result.returncode == 0, result.stderr
    doc: dict[str, Any] = json.loads(result.stdout)
    assert doc["rejected"] == [0]
    assert doc["frames"][0] > 1700  # the whole PTP (174 s) at 10 Hz
    limits = default_robot().limits
    flown = [q for q in doc["quantities"] if q["nominal_source"] == "flown"]
    assert {q["quantity"] for q in flown} == {
        name for name, spec in QUANTITIES.items() if spec.source == "frame"
    }
    for q in flown:
        bands = limits[q["quantity"]]
        assert q["clear"] is True, q
        assert bands.classify(q["nominal"]) is None, q
        least = min(m for m in q["margins"].values() if m is not None)
        assert least > 1.0, q
    # what the motion does: joint 4 lags its command (the largest tracking error), the arm
    # passes no closer than the flight rules' 0.10 m
    by_name = {q["quantity"]: q for q in flown}
    assert by_name["joint_tracking_error_deg"]["channel"] == "joint4"
    assert 1.0 < by_name["joint_tracking_error_deg"]["nominal"] < 2.0
    assert by_name["clearance_m"]["nominal"] > 0.10


def test_the_link_quantities_are_the_outage_s() -> None:
    nominal = link_nominal(LinkNominal(outage_s=30.0, delay_s=3.0, telemetry_rate_hz=10.0))
    assert nominal == {"frames_behind": 361, "frame_age_s": pytest.approx(36.1)}
    limits = default_robot().limits
    # the demo's outage may raise a watch, never more
    for name, value in nominal.items():
        assert limits[name].classify(value) is limits[name].thresholds[0][0]


def test_margins() -> None:
    high = QuantityRow("body_rate_degps", "deg/s", "high", False, 0.1, "", (0.1,), {"watch": 0.15})
    low = QuantityRow("clearance_m", "m", "low", True, 0.12, "", (0.12,), {"watch": 0.08})
    assert high.margins["watch"] == pytest.approx(1.5) and high.clear
    assert low.margins["watch"] == pytest.approx(1.5) and low.clear
    none = QuantityRow("frame_age_s", "s", "high", False, None, "", (), {"watch": 10.0})
    assert none.margins == {"watch": None} and none.clear is None
    assert not math.isnan(high.to_dict()["margins"]["watch"])
