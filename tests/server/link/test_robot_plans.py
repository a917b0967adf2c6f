"""The ground plans for a robot a request names, never a file it is sent (issue 12).

``POST /api/plans`` takes ``"robot": NAME``: a description shipped under ``examples/robots/``
or given to the server at its start (``Settings.robot_files``, ``serve --robot``). The plan
records the robot; the post-pass work finds the robot's model by the plan's hash.
"""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from planner.description import EXAMPLES_DIR
from planner.plan import Plan
from server.api.errors import status_of
from server.app import create_app
from server.services.errors import DomainError
from server.services.robots import known_robots, model_for_plan, resolve_robot
from server.settings import ApiToken, Role, Settings
from server.storage.db import sqlite_url
from tests.server.storage.factories import make_plan

OPERATOR = {"Authorization": "Bearer o-token"}
TOKENS = {"o-token": ApiToken(name="otto", role=Role.OPERATOR)}
ORIHIME_DIR = EXAMPLES_DIR / "orihime"


def _renamed_orihime(tmp_path: Path, name: str) -> Path:
    """Orihime's files under another name, outside the shipped examples."""
    folder = tmp_path / name
    folder.mkdir()
    shutil.copy(ORIHIME_DIR / "orihime.urdf", folder / "orihime.urdf")
    text = (ORIHIME_DIR / "orihime.toml").read_text()
    (folder / f"{name}.toml").write_text(text.replace('name = "orihime"', f'name = "{name}"', 1))
    return folder / f"{name}.toml"


@pytest.fixture()
def own_robot(tmp_path: Path) -> Path:
    return _renamed_orihime(tmp_path, "kengyu")


@pytest.fixture()
def client(tmp_path: Path, own_robot: Path) -> Iterator[TestClient]:
    settings = Settings(
        data_dir=tmp_path,
        database_url=sqlite_url(tmp_path),
        tokens=TOKENS,
        robot_files=(own_robot,),
    )
    with TestClient(create_app(settings)) as c:
        yield c


def test_the_server_knows_the_shipped_robots_and_its_own(tmp_path: Path, own_robot: Path) -> None:
    plain = Settings(data_dir=tmp_path)
    assert {"ets7", "orihime"} <= set(known_robots(plain))
    assert "kengyu" not in known_robots(plain)
    settings = Settings(data_dir=tmp_path, robot_files=(own_robot,))
    assert resolve_robot(settings, "kengyu") == own_robot.resolve()
    assert resolve_robot(settings, "orihime") == (ORIHIME_DIR / "orihime.toml").resolve()
    assert resolve_robot(settings, None) is None
    for name in ("nobody", str(own_robot), "../orihime/orihime.toml"):
        with pytest.raises(DomainError) as caught:
            resolve_robot(plain, name)
        assert (status_of(caught.value), caught.value.code) == (422, "unknown_robot")
        assert "it knows ['ets7', 'orihime']" in caught.value.message


def test_an_operator_plans_for_a_named_robot(client: TestClient, own_robot: Path) -> None:
    body = {"experiment": "ptp", "parameters": {"settle_s": 0.25}, "robot": "kengyu"}
    response = client.post("/api/plans", json=body, headers=OPERATOR)
    assert response.status_code == 201, response.text
    document = client.get(f"/api/plans/{response.json()['id']}/document", headers=OPERATOR)
    plan = Plan.from_json(document.text)
    assert plan.robot == "kengyu" and len(plan.initial_joints_rad) == 7
    # the robot's [experiments.ptp] goal (pose B), not ETS-VII's
    assert plan.command_joints_rad.shape[1] == 7
    # the plan's robot's model is found again by its hash for the recording and analyses
    model = model_for_plan(plan, (str(own_robot),))
    assert model is not None and model.n_joints == 7


def test_a_robot_the_server_does_not_know_is_422_and_no_file_is_read(client: TestClient) -> None:
    for name in ("nobody", "/etc/passwd", "../../examples/robots/orihime/orihime.toml"):
        body = {"experiment": "ptp", "parameters": {}, "robot": name}
        response = client.post("/api/plans", json=body, headers=OPERATOR)
        assert response.status_code == 422, response.text
        error = response.json()["error"]
        assert error["code"] == "unknown_robot"
        assert "it knows ['ets7', 'kengyu', 'orihime']" in error["message"]
    validation = client.post(
        "/api/plans/validate",
        json={"experiment": "ptp", "parameters": {}, "robot": "nobody"},
        headers=OPERATOR,
    )
    assert validation.status_code == 200
    assert validation.json()["errors"][0]["code"] == "unknown_robot"


def test_the_model_of_a_plan_is_its_robots() -> None:
    assert model_for_plan(make_plan()) is None  # ETS-VII: the built-in model
    stranger = replace(make_plan(n_joints=7), robot="stranger", robot_hash="ab" * 32)
    with pytest.raises(DomainError) as caught:
        model_for_plan(stranger)
    assert (status_of(caught.value), caught.value.code) == (409, "robot_unknown")
