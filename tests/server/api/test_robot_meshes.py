"""``GET /api/robots/{name}/meshes/...``: a vendor robot's visual meshes, as its URDF for
viewers points to them; only the files its description names, byte for byte; 404 with the
reason for anything else (an unknown key, a path that tries to leave, a robot without
meshes), 422 for a malformed name, a viewer's token required."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from planner.description import load_robot
from server.app import create_app
from server.settings import Settings
from tests.support.api import TOKENS, VIEWER
from tests.support.vendor import meshed_robot


@pytest.fixture(scope="module")
def ur5_toml(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return meshed_robot(tmp_path_factory.mktemp("ur5"), "ur5")


@pytest.fixture(scope="module")
def ur5_client(
    module_database_url: str, tmp_path_factory: pytest.TempPathFactory, ur5_toml: Path
) -> Iterator[TestClient]:
    """One application per module and backend: the tests read (one adds a pass of its own)."""
    settings = Settings(
        data_dir=tmp_path_factory.mktemp("app"),
        database_url=module_database_url,
        tokens=TOKENS,
        robot_files=(ur5_toml,),
    )
    with TestClient(create_app(settings)) as c:
        yield c


def _error(response: object, status: int, code: str) -> str:
    assert response.status_code == status, response.text  # type: ignore[attr-defined]
    body = response.json()  # type: ignore[attr-defined]
    assert body["error"]["code"] == code
    message: str = body["error"]["message"]
    return message


def test_the_urdf_points_each_link_at_its_vendor_mesh_and_each_is_served(
    ur5_client: TestClient, ur5_toml: Path
) -> None:
    robot = load_robot(ur5_toml)
    response = ur5_client.get("/api/robots/ur5/urdf", headers=VIEWER)
    assert response.status_code == 200
    root = ET.fromstring(response.text)
    meshes = {
        link.get("name"): [m.get("filename") for m in link.iter("mesh")]
        for link in root.iter("link")
    }
    # the UR5's seven visual meshes, each on the link of the body that carries it
    assert meshes["base_link"] == ["/api/robots/ur5/meshes/0/base.dae"]
    assert meshes["upper_arm_link"] == ["/api/robots/ur5/meshes/2/upperarm.dae"]
    assert meshes["wrist_3_link"] == ["/api/robots/ur5/meshes/6/wrist3.dae"]
    # a meshed link draws no cylinder; the base keeps its cube
    assert not list(root.find("link[@name='upper_arm_link']").iter("cylinder"))  # type: ignore[union-attr]
    assert root.find("link[@name='base_link']/visual/geometry/box") is not None
    served = 0
    for urls in meshes.values():
        for url in urls:
            got = ur5_client.get(url, headers=VIEWER)
            assert got.status_code == 200, got.text
            assert got.headers["content-type"].startswith("model/vnd.collada+xml")
            key = url.removeprefix("/api/robots/ur5/meshes/")
            assert got.content == robot.mesh_files[key].read_bytes()
            served += 1
    assert served == len(robot.visual_meshes) == 7


def test_the_placement_puts_the_mesh_where_the_vendor_urdf_does(ur5_toml: Path) -> None:
    """At the zero pose the export's upper-arm link frame plus its visual origin is the
    vendor's upper_arm_link frame (in the robot frame): the shoulder joint at the robot
    origin's height, rotated about y by the vendor's 90 degrees."""
    robot = load_robot(ur5_toml)
    [upper] = [m for m in robot.visual_meshes if m.link == "upper_arm_link"]
    assert upper.joint == 2
    link2 = robot.model.links[1]
    # the vendor's shoulder_lift_joint origin: xyz 0 0.13585 0, rpy 0 pi/2 0 (on the shoulder)
    np.testing.assert_allclose(upper.pos_robot_m, link2.joint_pos_robot_m, atol=1e-12)
    np.testing.assert_allclose(upper.pos_robot_m, [0.0, 0.13585, 0.0], atol=1e-9)
    np.testing.assert_allclose(
        upper.rot_robot_from_mesh, [[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]], atol=1e-9
    )


@pytest.mark.parametrize(
    "path",
    [
        "/api/robots/ur5/meshes/0/shoulder.dae",  # a file of the robot, but not under this key
        "/api/robots/ur5/meshes/99/base.dae",
        "/api/robots/ets7/meshes/0/base.dae",  # a robot drawn from primitives
    ],
)
def test_anything_else_is_404_with_the_reason(ur5_client: TestClient, path: str) -> None:
    response = ur5_client.get(path, headers=VIEWER)
    message = _error(response, 404, "unknown_mesh")
    assert "has no mesh" in message
    assert ("1/shoulder.dae" in message) or ("primitives" in message)


def test_a_path_that_climbs_out_never_reaches_a_file(ur5_client: TestClient) -> None:
    for path in (
        "/api/robots/ur5/meshes/0/../../../../../etc/passwd",
        "/api/robots/ur5/meshes/../../../etc/passwd",
        "/api/robots/ur5/meshes/0%2F..%2F..%2Fetc%2Fpasswd",
        "/api/robots/ur5/meshes/0/..%2F..%2Fur5.toml",
    ):
        response = ur5_client.get(path, headers=VIEWER)
        assert response.status_code in (404, 422), (path, response.status_code)
        assert response.json()["error"]["message"]  # a reason, in the one error shape
        assert "root:" not in response.text and "<robot" not in response.text


def test_an_unknown_robot_and_a_missing_token(ur5_client: TestClient) -> None:
    message = _error(
        ur5_client.get("/api/robots/kuka/meshes/0/base.dae", headers=VIEWER), 404, "unknown_robot"
    )
    assert "'kuka'" in message and "ur5" in message
    assert ur5_client.get("/api/robots/ur5/meshes/0/base.dae").status_code == 401


# foxglove-sdk schemas/jsonschema/ModelPrimitive.json's fields, restated and closed.
_MODEL_PRIMITIVE = {
    "type": "object",
    "additionalProperties": False,
    "required": ["pose", "scale", "color", "override_color", "url", "media_type", "data"],
    "properties": {
        "pose": {
            "type": "object",
            "additionalProperties": False,
            "properties": {
                "position": {"type": "object", "required": ["x", "y", "z"]},
                "orientation": {"type": "object", "required": ["x", "y", "z", "w"]},
            },
        },
        "scale": {"type": "object", "required": ["x", "y", "z"]},
        "color": {"type": "object", "required": ["r", "g", "b", "a"]},
        "override_color": {"type": "boolean"},
        "url": {"type": "string"},
        "media_type": {"type": "string"},
        "data": {"type": "string"},
    },
}


def test_the_recording_embeds_the_vendor_meshes_on_their_tf_frames(
    ur5_client: TestClient, ur5_toml: Path
) -> None:
    """A flown UR5 pass's MCAP from the ground: /robot_meshes holds one entity per visual
    mesh, the file's bytes exactly (base64), on a frame /tf moves, at the pose the viewers'
    URDF gives that mesh."""
    import base64
    import io
    import json

    import jsonschema_rs
    from mcap.reader import make_reader

    from planner.frames import matrix_from_quat_xyzw, rpy_from_matrix
    from telemetry.mcap import TOPIC_ROBOT_MESHES, TOPIC_TF
    from tests.support.api import recording_of_a_flown_pass

    ur5 = load_robot(ur5_toml)
    recording = recording_of_a_flown_pass(ur5_client, ur5, 8)
    updates, tf_children = [], set()
    for schema, channel, message in make_reader(io.BytesIO(recording)).iter_messages(
        topics=[TOPIC_ROBOT_MESHES, TOPIC_TF]
    ):
        doc = json.loads(message.data)
        if channel.topic == TOPIC_TF:
            tf_children |= {t["child_frame_id"] for t in doc["transforms"]}
        else:
            assert schema is not None and schema.name == "foxglove.SceneUpdate"
            updates.append(doc)
    [update] = updates
    assert len(update["entities"]) == len(ur5.visual_meshes) == 7
    validator = jsonschema_rs.validator_for(_MODEL_PRIMITIVE)
    urdf = ET.fromstring(robot_urdf_with_meshes(ur5))
    for entity, mesh in zip(update["entities"], ur5.visual_meshes, strict=True):
        assert entity["frame_id"] in tf_children
        assert entity["lifetime"] == {"sec": 0, "nsec": 0} and entity["frame_locked"] is True
        [model] = entity["models"]
        validator.validate(model)
        assert base64.b64decode(model["data"]) == ur5.mesh_files[mesh.key].read_bytes()
        assert model["media_type"] == "model/vnd.collada+xml"
        # the same place as the console's URDF draws it
        [visual] = [
            v
            for v in urdf.iter("visual")
            if (m := v.find("geometry/mesh")) is not None
            and m.get("filename", "").endswith("/" + mesh.key)
        ]
        origin = visual.find("origin")
        assert origin is not None
        assert (
            urdf.find(f"link[@name='{entity['frame_id']}']/visual[@name='{visual.get('name')}']")
            is not None
        )
        position = model["pose"]["position"]
        np.testing.assert_allclose(
            [position["x"], position["y"], position["z"]],
            [float(v) for v in origin.get("xyz", "").split()],
            atol=1e-12,
        )
        q = model["pose"]["orientation"]
        rot = matrix_from_quat_xyzw(np.array([q["x"], q["y"], q["z"], q["w"]]))
        np.testing.assert_allclose(
            rpy_from_matrix(rot), [float(v) for v in origin.get("rpy", "").split()], atol=1e-9
        )


def robot_urdf_with_meshes(robot: object) -> str:
    from server.services.robots import robot_urdf

    return robot_urdf(robot, mesh_base="/api/robots/ur5/meshes/")  # type: ignore[arg-type]
