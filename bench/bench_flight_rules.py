"""The flight-rules check of the whole ETS-VII demo pass against the planning of that pass.

Baseline measured in the same run: planning the pass (every experiment and one prediction of
the whole pass, ``plan_experiment("pass")``). Figure: checking that plan against every rule
(the servos' response on the fine grid, the clearance of every pair exact at every sample,
the attitude, wheel, joint-limit, hand-speed and window rules), its ratio to the planning,
and coal's distance queries per second within the check. Target (flight-rules issue): the
check under 20 % of the planning time.

The hulls' cost (a vendor's collision meshes as convex hulls, docs/planning.md): the UR5 of
example-robot-data (a dev dependency) on its 1 m cube, one PTP from its home pose to its
pose B checked twice in the same run: with the generated capsules (the baseline) and with
the URDF's own meshes as coal convex hulls; the ratio of the two checks, of the two loads,
and of coal's cost per distance query.
"""

from __future__ import annotations

import importlib.metadata
import re
import shutil
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
from _common import best_of, emit

from planner.catalogue import parameters_from_values, plan_experiment, resolve
from planner.description import default_robot, load_robot
from planner.plan import plan_for_robot

_VENDOR = Path(__file__).resolve().parents[1] / "tests" / "planner" / "vendor"


def _ur5(folder: Path, meshes: bool) -> Path:
    """The tests' UR5 description (tests/planner/vendor/ur5.toml) beside the package's URDF:
    generated capsules, or (``meshes``) the URDF's own collision meshes through
    ``[packages]`` with the generated allowed contacts."""
    files = importlib.metadata.files("example-robot-data") or []
    (urdf,) = [Path(str(f.locate())) for f in files if str(f).endswith("urdf/ur5_robot.urdf")]
    folder.mkdir()
    shutil.copyfile(urdf, folder / urdf.name)
    text = (_VENDOR / "ur5.toml").read_text()
    if meshes:
        text = text.replace("urdf_collision = false", "urdf_collision = true")
        text = re.sub(r"\[generated_collision\]\n(?:.+\n)*\n", "", text)
        text += (
            f'\n[packages]\n"example-robot-data" = "{urdf.parents[3]}"\n\n'
            "[flight_rules]\ngenerated_allowed_contact = true\n"
        )
    (folder / "ur5.toml").write_text(text)
    return folder / "ur5.toml"


def hull_figures() -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as tmp:
        capsule_toml, mesh_toml = _ur5(Path(tmp) / "c", False), _ur5(Path(tmp) / "m", True)
        load_capsules_s = best_of(lambda: load_robot(capsule_toml), repeat=3)
        load_meshes_s = best_of(lambda: load_robot(mesh_toml), repeat=3)
        capsules, hulls = load_robot(capsule_toml), load_robot(mesh_toml)
    params_type, _ = resolve("ptp")
    start = [float(v) for v in np.degrees(capsules.model.reference_joints)]
    params = parameters_from_values(
        params_type,
        {"start_joints_deg": start, "goal_joints_deg": [20.0, -70.0, 100.0, -110.0, -90.0, 10.0]},
    )
    plan = plan_experiment("ptp", params, robot=capsules)
    reports: dict[str, Any] = {}
    check_capsules_s = best_of(lambda: reports.update(c=capsules.check_plan(plan)), repeat=3)
    same = plan_for_robot(plan, hulls)  # the same motion, bound to the meshed description
    check_hulls_s = best_of(lambda: reports.update(h=hulls.check_plan(same)), repeat=3)
    c, h = reports["c"], reports["h"]
    assert hulls.collision is not None
    return {
        "ur5_hull_shapes": sum(
            1 for b in hulls.collision.bodies for s in b.shapes if s.kind == "convex"
        ),
        "ur5_load_capsules_s": load_capsules_s,
        "ur5_load_meshes_s": load_meshes_s,
        "ur5_load_meshes_over_capsules": load_meshes_s / load_capsules_s,
        "ur5_check_capsules_s": check_capsules_s,
        "ur5_check_hulls_s": check_hulls_s,
        "ur5_check_hulls_over_capsules": check_hulls_s / check_capsules_s,
        "ur5_queries_capsules": c.n_queries,
        "ur5_queries_hulls": h.n_queries,
        "ur5_per_query_hulls_over_capsules": (check_hulls_s / h.n_queries)
        / (check_capsules_s / c.n_queries),
        "ur5_pairs_capsules": c.n_pairs,
        "ur5_pairs_hulls": h.n_pairs,
        "ur5_clearance_capsules_m": c.row("clearance").value,
        "ur5_clearance_hulls_m": h.row("clearance").value,
        "ur5_both_pass": c.passed and h.passed,
    }


def main() -> None:
    robot = default_robot()
    params_type, _ = resolve("pass")
    params = parameters_from_values(params_type, {})
    plans = []
    planning_s = best_of(lambda: plans.append(plan_experiment("pass", params)), repeat=2)
    plan = plans[-1]
    reports = []
    check_s = best_of(lambda: reports.append(robot.check_plan(plan)), repeat=3)
    report = reports[-1]
    figures = {
        "baseline_plan_pass_s": planning_s,
        "check_pass_s": check_s,
        "check_over_planning": check_s / planning_s,
        "plan_duration_s": plan.duration_s,
        "step_s": report.step_s,
        "samples": report.n_samples,
        "pairs": report.n_pairs,
        "distance_queries": report.n_queries,
        "distance_queries_per_s": report.n_queries / check_s,
        "queries_brute_force_would_ask": report.n_samples * report.n_pairs,
        "min_clearance_m": report.row("clearance").value,
        "min_self_clearance_m": report.row("self_clearance").value,
        **hull_figures(),
    }
    emit(
        "flight_rules",
        figures,
        {"check_under_20_percent_of_planning": check_s < 0.2 * planning_s},
    )


if __name__ == "__main__":
    main()
