"""``hikoboshi report FILE.mcap`` of a vendor arm's pass: analysed with that arm's model,
found by the plan's description hash among ``--robot`` files, never with ETS-VII's. The UR5
has six joints as ETS-VII has: its frames would analyse, with the wrong arm's numbers."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from hikoboshi.cli import app
from planner.catalogue import parameters_from_values, plan_experiment, resolve
from planner.description import load_robot
from spacecraft.offline import fly_offline
from telemetry.mcap import write_mcap
from telemetry.recording import PassRecording
from tests.support.vendor import copy_robot

runner = CliRunner()


@pytest.fixture(scope="module")
def ur5(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The test description beside the vendor's URDF, copied from example-robot-data."""
    return copy_robot(tmp_path_factory.mktemp("robots"), "ur5")


@pytest.fixture(scope="module")
def ur5_mcap(ur5: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    robot = load_robot(ur5)
    params = parameters_from_values(
        resolve("ptp")[0], {}, defaults=robot.experiment_defaults("ptp")
    )
    plan = plan_experiment("ptp", params, robot=robot)
    flight = fly_offline(plan, robot=robot, seed=4)
    recording = PassRecording.from_frames("ur5 PTP", plan, flight.epoch_ns, flight.frames)
    path = tmp_path_factory.mktemp("ur5") / "ur5.mcap"
    write_mcap(recording, path, model=robot.model)
    return path


@pytest.mark.slow
def test_a_vendor_pass_is_reported_with_its_own_model(
    ur5: Path, ur5_mcap: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("HIKOBOSHI_ROBOTS", raising=False)
    refused = runner.invoke(app, ["report", str(ur5_mcap), "--out", str(tmp_path / "no")])
    assert refused.exit_code == 2, refused.output
    assert refused.output.startswith("error: ") and refused.output.count("\n") == 1
    assert "robot 'ur5'" in refused.output and "--robot FILE" in refused.output
    assert not (tmp_path / "no").exists(), "nothing written for a refused report"

    result = runner.invoke(
        app,
        ["report", str(ur5_mcap), "--robot", str(ur5), "--out", str(tmp_path / "r"), "--json"],
    )
    assert result.exit_code == 0, result.output
    doc = json.loads(result.stdout)
    statuses = {a["kind"]: a["status"] for a in doc["analyses"]}
    assert statuses["pass_analysis"] == "ok", doc["analyses"]
    report = json.loads((tmp_path / "r" / "report.json").read_text())
    assert report["tables"][0]["id"] == "plan_against_ours"
    assert "robot ur5 is not ETS-VII" in report["tables"][0]["title"]
