"""The console shows the robot of the pass: an Orihime (7-joint) pass draws Orihime from its
own URDF (fetched by its plan's robot hash) with seven joints in 3D and seven joint plots,
ETS-VII's pass draws ETS-VII; the planning page offers the server's robots, their named
poses, their joint counts and the defaults a plan for each takes (a vendor UR5's derived by
the tool, and marked so), and plans for the robot chosen."""

from __future__ import annotations

import json
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from planner.description import EXAMPLES_DIR, default_robot, load_robot
from planner.plan import plan_for_robot
from server.storage.db import sqlite_url
from tests.server.link.harness import Ground, running_ground
from tests.server.storage.factories import make_plan
from tests.support.vendor import copy_robot
from tests.support.web import OPERATOR_TOKEN, VIEWER_TOKEN, Console, stored_pass

pytestmark = pytest.mark.realtime  # flies a vehicle or serves a live link in wall time

ORIHIME = EXAMPLES_DIR / "orihime" / "orihime.toml"


@pytest.fixture
def ur5_toml(tmp_path: Path) -> Path:
    """The test UR5 (tests/planner/vendor/ur5.toml): its table gives the GJM's axis only."""
    return copy_robot(tmp_path, "ur5")


@pytest.fixture
def ground(tmp_path: Path, ur5_toml: Path) -> Iterator[Ground]:
    """The ground with the shipped robots and the UR5 given by file."""
    with running_ground(sqlite_url(tmp_path), robot_files=(ur5_toml,)) as g:
        yield g


def _stored_pass(ground: Ground, name: str, robot: Any, n_frames: int = 30) -> str:
    plan = plan_for_robot(make_plan(n_joints=robot.n_joints), robot)
    return stored_pass(ground, name, plan, n_frames)


def _urdf_requests(console: Console) -> list[str]:
    urls: list[str] = []
    console.page.on("request", lambda r: urls.append(r.url) if "urdf" in r.url else None)
    return urls


def _view3d(console: Console, pass_id: str, frames: int) -> dict[str, Any]:
    console.sign_in(VIEWER_TOKEN, f"#/live/{pass_id}")
    console.wait(f"() => window.hikoboshiLive?.frames() === {frames}", "the archive loaded")
    console.wait(
        f"() => Math.min(...window.hikoboshiLive.pointCounts()) >= {frames}", "plots drawn"
    )
    console.wait(
        "() => document.querySelector('[data-test=view3d]')?.dataset.joints !== undefined",
        "the 3D view built",
    )
    result: dict[str, Any] = console.page.evaluate(
        "() => { const v = document.querySelector('[data-test=view3d]');"
        " return {robot: v.dataset.robot, joints: Number(v.dataset.joints),"
        " views: document.querySelectorAll('[data-test=view3d]').length,"
        " plots: document.querySelectorAll('[data-test=joint-plots] > *').length}; }"
    )
    return result


@pytest.mark.parametrize(
    ("robot", "joints"),
    [(lambda: load_robot(ORIHIME), 7), (default_robot, 6)],
    ids=["orihime", "ets7"],
)
def test_a_pass_draws_its_own_robot_with_its_joints(
    console: Console, ground: Ground, robot: Any, joints: int
) -> None:
    description = robot()
    urls = _urdf_requests(console)
    pass_id = _stored_pass(ground, f"{description.name}-pass", description)
    shown = _view3d(console, pass_id, 30)
    assert shown == {"robot": description.name, "joints": joints, "views": 1, "plots": joints}
    assert [u.split(ground.url, 1)[1] for u in urls] == [
        f"/api/robots/by-hash/{description.content_sha256}/urdf"
    ]
    console.screenshot(f"{description.name}-pass-3d")


def _fields(page: Any) -> dict[str, str]:
    values: dict[str, str] = page.evaluate(
        "() => Object.fromEntries([...document.querySelectorAll('[data-field]')]"
        ".map((f) => [f.dataset.field, f.querySelector('input, select').value]))"
    )
    return values


def test_the_planning_page_plans_for_orihime_from_its_poses(
    console: Console, ground: Ground
) -> None:
    page = console.page
    console.sign_in(OPERATOR_TOKEN, "#/plan")
    page.wait_for_selector("[data-test=robot] option[value=orihime]", state="attached")
    options = page.eval_on_selector_all("[data-test=robot] option", "os => os.map(o => o.value)")
    assert "orihime" in options and "ets7" in options
    assert page.input_value("[data-test=robot]") == "ets7"  # the default, as before
    page.select_option("[data-test=experiment]", "ptp")
    page.wait_for_selector("[data-field=goal_joints_deg] input")
    assert _fields(page)["start_joints_deg"] == "0, 0, 0, 0, 0, 0"
    assert _derived(page) == []

    page.select_option("[data-test=robot]", "orihime")
    page.wait_for_function(
        "() => document.querySelector('[data-test=robot-info]').dataset.joints === '7'"
    )
    fields = _fields(page)
    # Orihime's own defaults ([experiments.ptp]), its seven joints
    assert fields["start_joints_deg"] == "0, 0, 0, 0, 0, 0, 0"
    assert fields["settle_s"] == "120"
    poses = page.eval_on_selector_all(
        "[data-test=pose-goal_joints_deg] option", "os => os.map(o => o.value)"
    )
    assert poses == ["", "A", "B", "C"]

    # Six values for a seven-joint robot: refused at the field, nothing planned.
    page.fill("[data-field=goal_joints_deg] input", "5, 0, 0, 0, 0, 0")
    page.click("[data-test=validate]")
    page.wait_for_function(
        "() => document.querySelector('[data-test=error-goal_joints_deg]').textContent !== ''"
    )
    assert "7 joints" in page.text_content("[data-test=error-goal_joints_deg]")

    page.select_option("[data-test=pose-goal_joints_deg]", "B")
    goal = [float(v) for v in page.input_value("[data-field=goal_joints_deg] input").split(",")]
    assert goal == [round(v, 4) for v in _pose_b_deg()]
    assert len(goal) == 7
    page.fill("[data-field=settle_s] input", "1")
    page.click("[data-test=create-plan]")
    page.wait_for_selector("[data-test=plan-robot]", timeout=120_000)
    assert page.text_content("[data-test=plan-robot]") == "robot orihime · 7 joints"
    console.wait(
        "() => document.querySelector('[data-test=view3d]')?.dataset.joints === '7'",
        "Orihime in 3D",
    )
    assert page.locator("[data-test=joint-plots] > *").count() == 7

    plan_id = page.url.rsplit("/", 1)[1]
    request = urllib.request.Request(
        f"{ground.url}/api/plans/{plan_id}/document",
        headers={"Authorization": f"Bearer {VIEWER_TOKEN}"},
    )
    with urllib.request.urlopen(request) as response:
        document = json.loads(response.read())
    assert document["robot"] == "orihime"
    assert document["robot_hash"] == load_robot(ORIHIME).content_sha256
    assert len(document["initial_joints_rad"]) == 7
    assert document["parameters"]["settle_s"] == 1.0
    console.screenshot("orihime-plan-preview")


def _derived(page: Any) -> list[str]:
    """The fields marked as derived by the tool for the chosen robot."""
    names: list[str] = page.eval_on_selector_all(
        "[data-field]:has(.derived)", "fs => fs.map((f) => f.dataset.field)"
    )
    return names


def _choose(page: Any, robot: str, experiment: str, joints: int) -> dict[str, str]:
    page.select_option("[data-test=robot]", robot)
    page.wait_for_function(
        f"() => document.querySelector('[data-test=robot-info]').dataset.joints === '{joints}'"
    )
    page.select_option("[data-test=experiment]", experiment)
    page.wait_for_selector("[data-field] input")
    return _fields(page)


def test_the_planning_form_shows_a_vendor_arms_own_defaults_derived_marked(
    console: Console, ground: Ground, ur5_toml: Path
) -> None:
    """The UR5's description gives none of these: the form shows what a plan of nothing
    typed takes for it (ETS-VII's distances scaled by its reach, pose A as the PTP start,
    more non-holonomic corrections), marked as the tool's, not ETS-VII's numbers."""
    page = console.page
    ur5 = load_robot(ur5_toml)
    console.sign_in(OPERATOR_TOKEN, "#/plan")
    page.wait_for_selector("[data-test=robot] option[value=ur5]", state="attached")

    ets7 = _choose(page, "ets7", "reactionless", 6)
    assert ets7["distance_m"] == "0.35" and ets7["out_speed_mps"] == "0.015"
    assert _derived(page) == []

    fields = _choose(page, "ur5", "reactionless", 6)
    derived = ur5.experiment_defaults("reactionless")
    assert fields["distance_m"] == str(derived["distance_m"]) == "0.146"
    assert fields["out_speed_mps"] == str(derived["out_speed_mps"]) == "0.006"
    assert fields["orientation_weight_m"] == "0.125"
    assert fields["ramp_s"] == "2"  # neither the description's nor derived: the catalogue's
    marked = ["back_speed_mps", "distance_m", "orientation_weight_m", "out_speed_mps"]
    assert sorted(_derived(page)) == marked
    title = page.get_attribute("[data-field=distance_m] input", "title")
    assert title is not None and "derived by the planner for this robot" in title

    # PTP from pose A (blank: the robot's own), not ETS-VII's stretched all-zero pose
    fields = _choose(page, "ur5", "ptp", 6)
    assert fields["start_joints_deg"] == "" and _derived(page) == ["start_joints_deg"]

    fields = _choose(page, "ur5", "nonholonomic", 6)
    assert fields["max_corrections"] == "12"
    phi_end = [float(v) for v in fields["phi_end_deg"].split(",")]
    assert phi_end == [0.0, -90.0, 90.0, -90.0, -90.0, 0.0]  # pose A
    assert sorted(_derived(page)) == ["max_corrections", "phi_end_deg", "phi_init_deg"]

    # the description's own value is not marked; the GJM's distance is derived
    fields = _choose(page, "ur5", "gjm", 6)
    assert fields["approach_axis_hand"] == "0, 0, 1"
    assert fields["approach_distance_m"] == "0.092"
    assert _derived(page) == ["approach_distance_m"]
    console.screenshot("ur5-plan-form-derived")


def _pose_b_deg() -> list[float]:
    import numpy as np

    from planner.dynamics import DynamicsWorkspace

    orihime = load_robot(ORIHIME)
    joints = orihime.target_joints_rad("B", DynamicsWorkspace(orihime.model), experiment="t")
    return [float(v) for v in np.degrees(joints)]
