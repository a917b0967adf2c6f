"""``hikoboshi plan``: the contract other tools rely on (real subprocesses)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

HIKOBOSHI = [sys.executable, "-m", "hikoboshi"]


def run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*HIKOBOSHI, *args], capture_output=True, text=True, timeout=600)


@pytest.fixture(scope="module")
def ptp_planned(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """``hikoboshi plan ptp --out FILE --json`` (no --robot: ETS-VII), run once for the
    module's tests of the PTP file (read only): the file and stdout."""
    out = tmp_path_factory.mktemp("ptp") / "ptp.json"
    result = run("plan", "ptp", "--out", str(out), "--json")
    assert result.returncode == 0, result.stderr
    return out, result.stdout


@pytest.mark.parametrize(
    ("experiment", "kinds"),
    [
        ("ptp", {"ptp", "settle"}),
        ("reactionless", {"reactionless", "hold"}),
        ("gjm", {"gjm", "hold"}),
    ],
)
def test_plan_writes_the_documented_file(
    tmp_path: Path, experiment: str, kinds: set[str], request: pytest.FixtureRequest
) -> None:
    if experiment == "ptp":
        out, stdout = request.getfixturevalue("ptp_planned")
    else:
        out = tmp_path / f"{experiment}.json"
        result = run("plan", experiment, "--out", str(out), "--json")
        assert result.returncode == 0, result.stderr
        stdout = result.stdout
    doc = json.loads(out.read_text())
    assert doc["experiment"] == experiment
    assert len(doc["initial_joints_rad"]) == 6
    times = np.array([c["t_s"] for c in doc["commands"]])
    np.testing.assert_array_equal(np.diff(times), 0.25)
    assert times[0] == 0.0
    assert all(len(c["joints_rad"]) == 6 for c in doc["commands"])
    assert {s["kind"] for s in doc["segments"]} == kinds
    for seg in doc["segments"]:
        assert set(seg) >= {"name", "kind", "t_start_s", "t_end_s"}
        assert 0.0 <= seg["t_start_s"] <= seg["t_end_s"] <= times[-1]
    assert json.loads(stdout)["out"] == str(out)


def test_plan_help_lists_the_parameters() -> None:
    result = run("plan", "--help")
    assert result.returncode == 0
    for name in ("out_speed_mps", "approach_distance_m", "offset_scale", "window_s"):
        assert name in result.stdout


@pytest.mark.parametrize(
    ("args", "reason"),
    [
        (["ptp", "--set", "nope=1"], "unknown parameter 'nope'"),
        (["ptp", "--set", "settle_s=abc"], "parameter settle_s"),
        (["ptp", "--set", "goal_joints_deg=0,0,175,0,0,0"], "joint 3 at 175.000 deg exceeds"),
        (["reactionless", "--set", "out_speed_mps=0.03"], "deg/s exceeds limit 3.000 deg/s"),
        (["gjm", "--set", "approach_s=3.1"], "approach_s"),
        (["teleport"], "unknown experiment 'teleport'"),
        (["ptp", "--optimise-offset"], "coordination experiment only"),
    ],
)
def test_bad_parameters_exit_with_one_line_and_write_nothing(
    tmp_path: Path, args: list[str], reason: str
) -> None:
    out = tmp_path / "plan.json"
    result = run("plan", *args[:1], "--out", str(out), *args[1:])
    assert result.returncode != 0
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and reason in lines[0], result.stderr
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []  # no temporary file left behind either


ORIHIME = Path(__file__).resolve().parents[1] / "examples" / "robots" / "orihime" / "orihime.toml"


def test_plan_for_another_robot_takes_its_description(
    tmp_path: Path, ptp_planned: tuple[Path, str]
) -> None:
    out = tmp_path / "reactionless.json"
    result = run("plan", "--robot", str(ORIHIME), "reactionless", "--out", str(out), "--json")
    assert result.returncode == 0, result.stderr
    doc = json.loads(out.read_text())
    assert doc["robot"] == "orihime" and len(doc["robot_hash"]) == 64
    assert len(doc["initial_joints_rad"]) == 7
    assert all(len(c["joints_rad"]) == 7 for c in doc["commands"])
    assert doc["parameters"]["distance_m"] == 0.2  # Orihime's [experiments.reactionless]
    assert json.loads(result.stdout)["metrics"]["peak_attitude_deg"] < 0.01
    # without --robot: ETS-VII, as before
    ets7, _ = ptp_planned
    assert json.loads(ets7.read_text())["robot"] == "ets7"


def test_plan_refuses_an_experiment_the_robot_cannot_give(tmp_path: Path) -> None:
    import shutil

    folder = tmp_path / "robot"
    shutil.copytree(ORIHIME.parent, folder)
    toml = folder / "orihime.toml"
    lines = toml.read_text().splitlines()
    start = lines.index("[poses.B]")
    end = next(i for i in range(start + 1, len(lines)) if lines[i].startswith("["))
    toml.write_text("\n".join(lines[:start] + lines[end:]) + "\n")
    out = tmp_path / "plan.json"
    result = run("plan", "--robot", str(toml), "reactionless", "--out", str(out))
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "has no pose 'B'" in lines[0], result.stderr
    assert not out.exists()


def test_a_plan_into_the_base_exits_3_naming_the_bodies_and_is_still_written(
    tmp_path: Path,
) -> None:
    """The issue's plan: the hand driven into ETS-VII's base box. Exit 3, the failing rule on
    stderr with the two bodies, the file written with its rules table; ``plan check`` says
    the same of the file, as text and as JSON."""
    out = tmp_path / "bad.json"
    result = run("plan", "ptp", "--set", "goal_joints_deg=90,120,60,0,0,0", "--out", str(out))
    assert result.returncode == 3, result.stderr
    assert "flight rule failed: clearance" in result.stderr
    assert "base_link and hand" in result.stderr
    doc = json.loads(out.read_text())
    assert doc["flight_rules"]["passed"] is False
    failing = [r for r in doc["flight_rules"]["rows"] if r["verdict"] == "fail"]
    assert [r["rule"] for r in failing] == ["clearance"]
    assert set(failing[0]["bodies"]) == {"base_link", "hand"}

    checked = run("plan", "check", str(out), "--json")
    assert checked.returncode == 3
    report = json.loads(checked.stdout)["flight_rules"]
    assert report["passed"] is False
    assert report["rows"] == doc["flight_rules"]["rows"]


def test_plan_check_passes_a_good_plan_and_refuses_another_robots(
    ptp_planned: tuple[Path, str],
) -> None:
    out, _ = ptp_planned
    checked = run("plan", "check", str(out))
    assert checked.returncode == 0, checked.stderr
    assert "clearance" in checked.stdout and "FAIL" not in checked.stdout
    other = run("plan", "check", str(out), "--robot", "examples/robots/orihime/orihime.toml")
    assert other.returncode == 2
    assert "not 'orihime'" in other.stderr
    assert run("plan", "check").returncode == 2  # no FILE


def test_plan_upload_refuses_with_one_line_before_it_reaches_a_ground(
    tmp_path: Path, ptp_planned: tuple[Path, str]
) -> None:
    """No token, no file, no ground: status 2 and the reason (the upload itself, to a
    running ground: tests/server/link/test_plan_upload_e2e.py)."""
    out, _ = ptp_planned
    env = {k: v for k, v in os.environ.items() if k != "HIKOBOSHI_TOKEN"}
    cases = [
        (["plan", "upload", str(out)], env, "needs an operator's token"),
        (["plan", "upload"], {**env, "HIKOBOSHI_TOKEN": "t"}, "plan upload needs the plan FILE"),
        (
            ["plan", "upload", str(tmp_path / "none.json")],
            {**env, "HIKOBOSHI_TOKEN": "t"},
            "none.json: No such file",
        ),
        (
            ["plan", "upload", str(out), "--url", "http://127.0.0.1:9"],
            {**env, "HIKOBOSHI_TOKEN": "t"},
            "is the ground service at http://127.0.0.1:9 running?",
        ),
    ]
    for args, environment, reason in cases:
        result = subprocess.run(
            [*HIKOBOSHI, *args], capture_output=True, text=True, timeout=600, env=environment
        )
        assert result.returncode == 2, (args, result.stderr)
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and reason in lines[0], result.stderr
