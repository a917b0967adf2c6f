"""The 3D view of a vendor robot draws its vendor's visual meshes: a UR5 pass (the UR5 of
example-robot-data, its ``package://`` meshes found through ``[packages]``) loads each of the
seven DAE files its URDF names from ``GET /api/robots/ur5/meshes/...``, once, with the
viewer's token, and none fails; ETS-VII's view asks for no mesh at all."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from planner.description import default_robot, load_robot
from planner.plan import plan_for_robot
from server.storage.db import sqlite_url
from tests.server.link.harness import Ground, running_ground
from tests.server.storage.factories import make_plan
from tests.support.vendor import meshed_robot
from tests.support.web import VIEWER_TOKEN, Console, stored_pass

pytestmark = pytest.mark.realtime  # flies a vehicle or serves a live link in wall time


@pytest.fixture
def ur5_toml(tmp_path: Path) -> Path:
    return meshed_robot(tmp_path, "ur5")


@pytest.fixture
def ground(tmp_path: Path, ur5_toml: Path) -> Iterator[Ground]:
    with running_ground(sqlite_url(tmp_path), robot_files=(ur5_toml,)) as g:
        yield g


def _open_view(console: Console, pass_id: str) -> dict[str, str]:
    console.sign_in(VIEWER_TOKEN, f"#/live/{pass_id}")
    console.wait(
        "() => document.querySelector('[data-test=view3d]')?.dataset.meshes !== undefined",
        "the 3D view built",
    )
    console.wait(
        "() => { const d = document.querySelector('[data-test=view3d]').dataset;"
        " return Number(d.meshesLoaded) + Number(d.meshesFailed) >= Number(d.meshes); }",
        "every mesh loaded or failed",
    )
    shown: dict[str, str] = console.page.evaluate(
        "() => ({...document.querySelector('[data-test=view3d]').dataset})"
    )
    return shown


def test_a_vendor_robot_is_drawn_with_its_own_meshes(
    console: Console, ground: Ground, ur5_toml: Path
) -> None:
    ur5 = load_robot(ur5_toml)
    assert len(ur5.visual_meshes) == 7
    requests: list[tuple[str, str | None]] = []
    console.page.on(
        "request",
        lambda r: (
            requests.append((r.url, r.headers.get("authorization")))
            if "/meshes/" in r.url
            else None
        ),
    )
    pass_id = stored_pass(
        ground, "ur5-pass", plan_for_robot(make_plan(n_joints=6), ur5), n_frames=20
    )
    shown = _open_view(console, pass_id)
    assert shown["robot"] == "ur5" and shown["joints"] == "6"
    # the robot and its translucent twin ask for the same seven files: fetched once each
    assert shown["meshes"] == "7"
    assert shown["meshesLoaded"] == "7" and shown["meshesFailed"] == "0"
    paths = sorted(url.split(ground.url, 1)[1] for url, _ in requests)
    assert paths == sorted(f"/api/robots/ur5/meshes/{v.key}" for v in ur5.visual_meshes)
    assert all(auth == f"Bearer {VIEWER_TOKEN}" for _, auth in requests)
    console.screenshot("ur5-pass-meshes")


def test_a_robot_without_meshes_asks_for_none(console: Console, ground: Ground) -> None:
    requests: list[str] = []
    console.page.on("request", lambda r: requests.append(r.url) if "/meshes/" in r.url else None)
    ets7 = default_robot()
    pass_id = stored_pass(
        ground, "ets7-pass", plan_for_robot(make_plan(n_joints=6), ets7), n_frames=20
    )
    shown = _open_view(console, pass_id)
    assert shown["robot"] == "ets7"
    assert shown["meshes"] == "0" and requests == []
