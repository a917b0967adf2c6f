"""``hikoboshi plan campaign``: the issue's command as written (default assignment, three
passes) in a fresh process with every socket refused, its files (a plan per pass and the
campaign file); bad input refused with status 2 and one line naming the fault."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest

from mission import MISSIONS_DIR
from mission.campaign import load_campaign
from planner.plan import Plan
from server.operations.campaign import DEFAULT_ASSIGNMENT
from tests.support.offline import run_offline

ETS7 = str(MISSIONS_DIR / "ets7-1999.toml")


def run(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return run_offline(*args, cwd=cwd, timeout_s=900)


@pytest.mark.slow
def test_the_issue_s_command_writes_a_plan_per_pass_and_the_campaign(tmp_path: Path) -> None:
    result = run(
        "plan", "campaign", "--mission", ETS7, "--start", "1999-09-30T00:00:00Z", cwd=tmp_path
    )
    assert result.returncode == 0, result.stderr
    out = tmp_path / "out" / "campaign"  # the default --out
    assert "wrote" in result.stdout and "campaign.json" in result.stdout
    record = load_campaign(out / "campaign.json")
    assert [p.experiments for p in record.passes] == list(DEFAULT_ASSIGNMENT)
    previous_end = None
    for p in record.passes:
        assert p.plan_path == out / f"pass-{p.index}.plan.json"
        plan = Plan.from_json(p.plan_path.read_text())
        assert plan.experiment == "pass"
        assert plan.parameters["experiments"] == list(p.experiments)
        assert plan.flight_rules is not None
        assert plan.flight_rules["passed"] is True
        assert all(row["verdict"] == "pass" for row in plan.flight_rules["rows"])
        assert p.window.net_start_utc <= p.plan_start_utc
        assert p.plan_end_utc <= p.window.net_end_utc
        if previous_end is not None:
            assert p.plan_start_utc > previous_end
        previous_end = p.plan_end_utc
    assert record.passes[0].window.relay in {"TDRS-East", "TDRS-West"}


@pytest.mark.slow
def test_json_names_the_files_and_an_assignment_of_one_pass(tmp_path: Path) -> None:
    result = run(
        "plan",
        "campaign",
        "--mission",
        ETS7,
        "--start",
        "1999-09-30T03:00:00Z",
        "--assign",
        "nonholonomic",
        "--out",
        str(tmp_path / "c"),
        "--json",
        cwd=tmp_path,
    )
    assert result.returncode == 0, result.stderr
    doc = json.loads(result.stdout)
    assert doc["out"] == str(tmp_path / "c" / "campaign.json")
    assert [p["experiments"] for p in doc["passes"]] == [["nonholonomic"]]
    assert Path(doc["passes"][0]["plan_file"]).is_file()
    assert doc["passes"][0]["window"]["aos_utc"] >= "1999-09-30T03:00:00"


@pytest.mark.parametrize(
    ("args", "reason"),
    [
        (["--start", "1999-09-30T00:00:00Z"], "needs --mission FILE"),
        (["--mission", ETS7], "needs --start ISO8601"),
        (["--mission", ETS7, "--start", "1999-09-30T00:00:00"], "has no UTC offset"),
        (["--mission", "nowhere.toml", "--start", "1999-09-30T00:00:00Z"], "no such file"),
        (
            ["--mission", ETS7, "--start", "1999-09-30T00:00:00Z", "--assign", "ptp/warp"],
            "pass 2: unknown experiment 'warp'",
        ),
        (
            ["--mission", ETS7, "--start", "2001-01-01T00:00:00Z"],
            "over the 60 day limit",
        ),
        (
            ["--mission", ETS7, "--start", "1999-09-30T00:00:00Z", "--set", "window_s=10"],
            "takes no --set",
        ),
    ],
)
def test_bad_input_exits_2_with_one_line(args: list[str], reason: str, tmp_path: Path) -> None:
    result = run("plan", "campaign", *args, cwd=tmp_path)
    assert result.returncode == 2, result.stdout + result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and reason in lines[0], lines
    assert not (tmp_path / "out").exists()


def test_campaign_options_belong_to_the_campaign(tmp_path: Path) -> None:
    result = run("plan", "ptp", "--out", "p.json", "--mission", ETS7, cwd=tmp_path)
    assert result.returncode == 2
    assert "for plan campaign" in result.stderr
