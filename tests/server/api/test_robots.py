"""``/api/robots``: the robots the server plans for, each one's URDF by name, and the URDF of
a plan's robot by its description hash (a robot given by file included); 404 with the reason
for an unknown robot, 422 for a malformed name or hash, a viewer's token required. A vendor
arm's listed experiment defaults are the ones its plans take (the tool's derived ones
marked), and a plan of those values typed is the plan of none."""

from __future__ import annotations

import shutil
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from planner.catalogue import experiments, resolve
from planner.description import EXAMPLES_DIR, default_robot, load_robot
from planner.model import default_model
from planner.plan import plan_for_robot
from planner.urdf import urdf_xml
from server.api.errors import status_of
from server.app import create_app
from server.services.errors import DomainError
from server.services.robots import robot_urdf, urdf_for_plan
from server.settings import Settings
from server.storage import repository as repo
from server.storage.db import sqlite_url
from tests.server.storage.factories import make_plan
from tests.support.api import OPERATOR, TOKENS, VIEWER, sessions
from tests.support.vendor import copy_robot

ORIHIME = EXAMPLES_DIR / "orihime" / "orihime.toml"
SPACECRAFT = {"Authorization": "Bearer s-token"}
#: For the tests that only ask the robots' routes (they read the robot files) and plan
#: validation (it plans in a worker and stores nothing): none of them touches the database,
#: so they ask one backend; the tests that store a plan or a pass keep both.
NO_DATABASE = pytest.mark.parametrize("database_url", ["sqlite"], indirect=True)


def _revolute(urdf: str) -> list[str]:
    root = ET.fromstring(urdf)
    return [j.get("name", "") for j in root.iter("joint") if j.get("type") == "revolute"]


def _error(response: object, status: int, code: str) -> str:
    assert response.status_code == status, response.text  # type: ignore[attr-defined]
    body = response.json()  # type: ignore[attr-defined]
    assert body["error"]["code"] == code
    message: str = body["error"]["message"]
    return message


@NO_DATABASE
def test_the_robots_list_their_joints_poses_hash_and_defaults(client: TestClient) -> None:
    response = client.get("/api/robots", headers=VIEWER)
    assert response.status_code == 200
    body = response.json()
    robots = {r["name"]: r for r in body["data"]}
    assert body["count"] == len(body["data"])
    assert {"ets7", "orihime"} <= set(robots)
    orihime, ets7 = robots["orihime"], robots["ets7"]
    assert orihime["n_joints"] == 7 and ets7["n_joints"] == 6
    assert orihime["robot_hash"] == load_robot(ORIHIME).content_sha256
    assert ets7["robot_hash"] == default_robot().content_sha256
    assert ets7["default"] is True and orihime["default"] is False
    assert [p["name"] for p in orihime["poses"]] == ["A", "B", "C"]
    assert all(len(p["joints_deg"]) == 7 for p in orihime["poses"])
    # B as the experiments take it: the IK of its hand pose near its written joints
    b = next(p for p in orihime["poses"] if p["name"] == "B")
    assert b["joints_deg"] == pytest.approx([25.0, -20.0, -10.0, 30.0, 20.0, -40.0, 15.0], abs=0.01)
    assert b["hand_pos_robot_m"] == pytest.approx([0.8908, 0.6018, 1.321])
    assert orihime["experiments"]["ptp"]["settle_s"] == 120.0
    assert len(orihime["experiments"]["nonholonomic"]["phi_init_deg"]) == 7
    assert len(orihime["joint_limits_deg"]) == 7
    assert orihime["urdf_url"] == "/api/robots/orihime/urdf"


@NO_DATABASE
def test_a_robots_urdf_by_name_is_its_own(client: TestClient) -> None:
    response = client.get("/api/robots/orihime/urdf", headers=VIEWER)
    assert response.status_code == 200
    assert response.headers["content-type"].startswith("application/xml")
    assert response.text == robot_urdf(load_robot(ORIHIME))
    assert ET.fromstring(response.text).get("name") == "orihime"
    assert len(_revolute(response.text)) == 7
    ets7 = client.get("/api/robots/ets7/urdf", headers=VIEWER)
    assert ets7.status_code == 200
    assert len(_revolute(ets7.text)) == 6
    # ETS-VII's by name is the document /api/model/urdf has always served
    assert ets7.text == client.get("/api/model/urdf", headers=VIEWER).text
    assert ets7.text == robot_urdf(default_robot())
    # the model's own export, with the keep-out equipment drawn on the base
    equipment = {"target_satellite", "task_board", "paddle_root_py", "paddle_root_ny"}
    drawn = ET.fromstring(ets7.text)
    assert equipment <= {link.get("name") for link in drawn.iter("link")}
    for joint in drawn.findall("joint"):
        child = joint.find("child")
        if child is not None and child.get("link") in equipment | {"antenna_ioc"}:
            drawn.remove(joint)
    for link in drawn.findall("link"):
        if link.get("name") in equipment | {"antenna_ioc"}:
            drawn.remove(link)
    assert ET.canonicalize(ET.tostring(drawn, encoding="unicode"), strip_text=True) == (
        ET.canonicalize(urdf_xml(default_model()), strip_text=True)
    )


@NO_DATABASE
def test_an_unknown_or_malformed_robot_is_refused_with_the_reason(client: TestClient) -> None:
    message = _error(client.get("/api/robots/hikari/urdf", headers=VIEWER), 404, "unknown_robot")
    assert "hikari" in message and "orihime" in message and "ets7" in message
    _error(client.get("/api/robots/bad%20name/urdf", headers=VIEWER), 422, "invalid_request")
    unknown = "0" * 64
    message = _error(
        client.get(f"/api/robots/by-hash/{unknown}/urdf", headers=VIEWER), 404, "unknown_robot"
    )
    assert unknown in message and "hikoboshi serve --robot FILE" in message
    _error(client.get("/api/robots/by-hash/ABC/urdf", headers=VIEWER), 422, "invalid_request")


@NO_DATABASE
@pytest.mark.parametrize(
    "path", ["/api/robots", "/api/robots/orihime/urdf", "/api/robots/by-hash/{hash}/urdf"]
)
def test_the_robots_need_a_viewers_token(client: TestClient, path: str) -> None:
    path = path.format(hash=load_robot(ORIHIME).content_sha256)
    _error(client.get(path), 401, "unauthorized")
    _error(client.get(path, headers={"Authorization": "Bearer nope"}), 401, "unauthorized")
    _error(client.get(path, headers=SPACECRAFT), 403, "forbidden")
    assert client.get(path, headers={"Authorization": "Bearer o-token"}).status_code == 200


def test_a_plans_robot_urdf_by_the_hash_its_document_records(client: TestClient) -> None:
    orihime = load_robot(ORIHIME)
    with sessions(client)() as session:
        record = repo.add_plan(
            session=session, plan=plan_for_robot(make_plan(n_joints=7), orihime), created_at_ns=0
        )
        session.commit()
        plan_id = record.id
    document = client.get(f"/api/plans/{plan_id}/document", headers=VIEWER).json()
    assert document["robot"] == "orihime"
    response = client.get(f"/api/robots/by-hash/{document['robot_hash']}/urdf", headers=VIEWER)
    assert response.status_code == 200
    assert response.text == robot_urdf(orihime)
    assert len(_revolute(response.text)) == 7


@pytest.fixture()
def renamed(tmp_path: Path) -> Path:
    """Orihime's description under another name, in a folder of its own (not shipped)."""
    folder = tmp_path / "hikari"
    folder.mkdir()
    shutil.copy(ORIHIME.parent / "orihime.urdf", folder / "orihime.urdf")
    text = ORIHIME.read_text().replace('name = "orihime"', 'name = "hikari"', 1)
    (folder / "hikari.toml").write_text(text)
    return folder / "hikari.toml"


@pytest.fixture()
def client_with_file(tmp_path: Path, renamed: Path) -> Iterator[TestClient]:
    """A ground given the file, on a database of its own (one ground a SQLite file: the
    ``client`` beside it is another ground)."""
    own = tmp_path / "with-file"
    settings = Settings(
        data_dir=own, database_url=sqlite_url(own), tokens=TOKENS, robot_files=(renamed,)
    )
    with TestClient(create_app(settings)) as c:
        yield c


@NO_DATABASE
def test_a_robot_given_by_file_is_listed_and_served_by_name_and_hash(
    client_with_file: TestClient, client: TestClient, renamed: Path
) -> None:
    hikari = load_robot(renamed)
    names = [r["name"] for r in client_with_file.get("/api/robots", headers=VIEWER).json()["data"]]
    assert "hikari" in names
    by_name = client_with_file.get("/api/robots/hikari/urdf", headers=VIEWER)
    by_hash = client_with_file.get(
        f"/api/robots/by-hash/{hikari.content_sha256}/urdf", headers=VIEWER
    )
    assert by_name.status_code == by_hash.status_code == 200
    assert by_name.text == by_hash.text == robot_urdf(hikari)
    assert ET.fromstring(by_name.text).get("name") == "hikari"
    # a server not given the file does not know it
    _error(client.get("/api/robots/hikari/urdf", headers=VIEWER), 404, "unknown_robot")
    _error(
        client.get(f"/api/robots/by-hash/{hikari.content_sha256}/urdf", headers=VIEWER),
        404,
        "unknown_robot",
    )


def test_the_recordings_urdf_is_the_plans_robots(renamed: Path) -> None:
    orihime = load_robot(ORIHIME)
    assert urdf_for_plan(make_plan()) is None  # ETS-VII: the built-in model's
    assert urdf_for_plan(plan_for_robot(make_plan(n_joints=7), orihime)) == robot_urdf(orihime)
    hikari_plan = plan_for_robot(make_plan(n_joints=7), load_robot(renamed))
    assert urdf_for_plan(hikari_plan, [renamed]) == robot_urdf(load_robot(renamed))
    with pytest.raises(DomainError) as refused:
        urdf_for_plan(hikari_plan)
    assert status_of(refused.value) == 409 and refused.value.code == "robot_unknown"


def test_the_grounds_recording_of_an_orihime_pass_attaches_orihime_urdf(
    client: TestClient,
) -> None:
    import io

    from telemetry.mcap import read_mcap, read_urdf
    from tests.support.api import recording_of_a_flown_pass

    orihime = load_robot(ORIHIME)
    recording = recording_of_a_flown_pass(client, orihime, 12)
    assert read_urdf(io.BytesIO(recording)) == ("orihime.urdf", robot_urdf(orihime))
    assert read_mcap(io.BytesIO(recording)).plan.robot == "orihime"


@pytest.fixture()
def ur5_toml(tmp_path: Path) -> Path:
    """The test UR5 (tests/planner/vendor/ur5.toml): a table for the GJM's axis only."""
    return copy_robot(tmp_path, "ur5")


@pytest.fixture()
def client_with_ur5(database_url: str, tmp_path: Path, ur5_toml: Path) -> Iterator[TestClient]:
    settings = Settings(
        data_dir=tmp_path, database_url=database_url, tokens=TOKENS, robot_files=(ur5_toml,)
    )
    with TestClient(create_app(settings)) as c:
        yield c


def _listed(client: TestClient, name: str) -> dict[str, Any]:
    response = client.get("/api/robots", headers=VIEWER)
    assert response.status_code == 200, response.text
    robot: dict[str, Any] = next(r for r in response.json()["data"] if r["name"] == name)
    return robot


@NO_DATABASE
def test_a_vendor_arms_defaults_are_the_ones_its_plans_take_derived_marked(
    client_with_ur5: TestClient, ur5_toml: Path
) -> None:
    ur5 = load_robot(ur5_toml)
    listed = _listed(client_with_ur5, "ur5")
    effective = listed["experiment_defaults"]
    derived = listed["derived_defaults"]
    assert set(effective) == set(derived) == set(experiments())
    for experiment in experiments():
        assert effective[experiment] == dict(ur5.experiment_defaults(experiment)), experiment
        own = ur5.experiments.get(experiment, {})
        assert derived[experiment] == sorted(set(effective[experiment]) - set(own)), experiment
    # the description's own table keeps its meaning: the GJM's axis, nothing derived in it
    assert listed["experiments"] == {"gjm": {"approach_axis_hand": [0.0, 0.0, 1.0]}}
    assert derived["gjm"] == ["approach_distance_m"]
    # scaled by the arm's reach (1.104 m over ETS-VII's 2.649 m), not ETS-VII's numbers
    reactionless = resolve("reactionless")[0]()
    assert effective["reactionless"]["distance_m"] == 0.146 != reactionless.distance_m
    assert effective["coordination"]["distance_m"] == 0.083
    assert effective["ptp"] == {"start_joints_deg": None}  # pose A, not ETS-VII's zeros
    assert effective["nonholonomic"]["phi_end_deg"] == [0.0, -90.0, 90.0, -90.0, -90.0, 0.0]
    assert effective["nonholonomic"]["max_corrections"] == 12
    assert derived["nonholonomic"] == ["max_corrections", "phi_end_deg", "phi_init_deg"]


@NO_DATABASE
def test_orihime_and_ets7_give_their_defaults_themselves(client: TestClient) -> None:
    """Their descriptions give every key their plans depend on: what the tool derives for
    ETS-VII is its own numbers, the catalogue's."""
    orihime = _listed(client, "orihime")
    assert orihime["experiment_defaults"]["reactionless"]["distance_m"] == 0.2
    assert "distance_m" not in orihime["derived_defaults"]["reactionless"]
    ets7 = _listed(client, "ets7")
    for experiment, keys in ets7["derived_defaults"].items():
        catalogue = resolve(experiment)[0]()
        for key in keys:
            assert ets7["experiment_defaults"][experiment][key] == getattr(catalogue, key)


def _as_typed(value: object) -> str:
    """A default as the planning form writes it into its field (web/src/pages/plan.ts)."""
    if isinstance(value, list):
        return ", ".join(_as_typed(v) for v in value)
    if isinstance(value, bool):
        return "true" if value else "false"
    return str(value)


@pytest.mark.slow
@NO_DATABASE
def test_a_plan_of_the_listed_defaults_typed_is_the_plan_of_none(
    client_with_ur5: TestClient,
) -> None:
    """Reactionless on the UR5: the experiment with the most derived keys (its distance,
    speeds and orientation weight scaled by reach)."""
    listed = _listed(client_with_ur5, "ur5")
    defaults = listed["experiment_defaults"]["reactionless"]
    typed = {k: _as_typed(v) for k, v in defaults.items() if v is not None}
    assert {"distance_m", "out_speed_mps", "back_speed_mps", "orientation_weight_m"} <= set(typed)

    def validate(parameters: dict[str, str]) -> dict[str, Any]:
        body = {"experiment": "reactionless", "robot": "ur5", "parameters": parameters}
        response = client_with_ur5.post("/api/plans/validate", json=body, headers=OPERATOR)
        assert response.status_code == 200, response.text
        result: dict[str, Any] = response.json()
        assert result["valid"] is True, result["errors"]
        return result

    untyped, from_form = validate({}), validate(typed)
    assert from_form["summary"] == untyped["summary"]
    summary = untyped["summary"]
    assert summary["parameters"]["distance_m"] == 0.146
