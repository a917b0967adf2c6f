"""The command-line contract other tools rely on (run as a real subprocess)."""

from __future__ import annotations

import json
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

HIKOBOSHI = [sys.executable, "-m", "hikoboshi"]


def run(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*HIKOBOSHI, *args], capture_output=True, text=True, timeout=120, cwd=cwd)


def test_quantities_json_at_pose_a() -> None:
    result = run("model", "quantities", "--joints-deg", "0,0,0,0,0,0", "--json")
    assert result.returncode == 0, result.stderr
    doc = json.loads(result.stdout)
    assert doc["total_mass_kg"] == pytest.approx(2690.4, abs=1e-9)
    np.testing.assert_allclose(doc["hand_position_robot_m"], [1.162, -0.267, 1.497], atol=1e-12)
    np.testing.assert_allclose(doc["hand_rpy_deg"], [0, 0, 0], atol=1e-12)
    assert np.shape(doc["generalized_jacobian"]) == (6, 6)
    assert np.shape(doc["base_reaction_map"]) == (3, 6)
    inertia = np.array(doc["system_inertia_com_kgm2"])
    assert inertia.shape == (3, 3)
    np.testing.assert_allclose(inertia, inertia.T, atol=1e-9)
    torque = np.array(doc["gravity_gradient_torque_nm"])
    # eq. (13): Earth-pointing, 3 mu / R^3 (-H_yz, H_xz, 0)
    coefficient = 3 * 3.986004418e14 / (6378.137e3 + 550e3) ** 3
    np.testing.assert_allclose(
        torque, coefficient * np.array([-inertia[1, 2], inertia[0, 2], 0.0]), rtol=1e-12
    )


def test_quantities_at_pose_b_match_the_paper() -> None:
    result = run("model", "quantities", "--joints-deg", "31.6,21.4,-8.8,77.4,0,68.6", "--json")
    doc = json.loads(result.stdout)
    # SPEC 1.2 gives B to the millimetre and degree with joints rounded to 0.1 deg.
    np.testing.assert_allclose(doc["hand_position_robot_m"], [1.170, 0.407, 0.490], atol=2e-3)
    np.testing.assert_allclose(doc["hand_rpy_deg"][1], 90.0, atol=0.1)


@pytest.mark.parametrize(
    ("joints", "reason"),
    [
        ("0,0,0", "needs 6 comma-separated angles, got 3"),
        ("0,0,abc,0,0,0", "value 3 is not a number"),
        ("0,0,0,0,0,nan", "value 6 is not finite"),
        ("0,0,0,0,171,0", "joint 5 at 171.000 deg exceeds limit 170.000 deg"),
    ],
)
def test_quantities_rejects_bad_input_with_one_line(joints: str, reason: str) -> None:
    result = run("model", "quantities", "--joints-deg", joints, "--json")
    assert result.returncode != 0
    assert result.stdout == ""
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and reason in lines[0], result.stderr


def test_urdf_command_prints_the_model() -> None:
    result = run("model", "urdf")
    assert result.returncode == 0, result.stderr
    root = ET.fromstring(result.stdout)
    links = {link.get("name") for link in root.iter("link")}
    assert {"base_link", "hand", *(f"link{i}" for i in range(1, 7))} <= links
    masses = sum(float(m.get("value", "0")) for m in root.iter("mass"))
    assert masses == pytest.approx(2690.4, abs=1e-9)


def test_demo_runs_and_reports_the_attitude_response(tmp_path: Path) -> None:
    result = run("ptp-demo", "--json", "--out", str(tmp_path / "demo"))
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)
    assert (tmp_path / "demo" / "summary.json").exists()
    assert (tmp_path / "demo" / "ptp_attitude.csv").read_text().count("\n") > 100
    # PTP A->B in free drift turns the base by degrees; eq. (10) predicts it closely.
    assert max(abs(v) for v in summary["simulated_final_rpy_deg"]) > 1.0
    assert summary["prediction_error_deg"] < 0.01
    assert summary["angular_momentum_drift_nms"] < 1e-7
