"""``hikoboshi calibrate`` (spacecraft.calibration): the attitude-control law recovered from a
pass flown with known gains, the written [acs] file, the paper fit's report and the CLI."""

from __future__ import annotations

import functools
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from hikoboshi.cli import app
from planner.description import load_acs_config
from planner.dynamics import DynamicsWorkspace
from planner.experiments import PtpParams, plan_ptp
from planner.model import default_model
from planner.plan import Plan
from spacecraft.calibration import gains_from_parameters, write_acs_config
from spacecraft.calibration_paper import fit_to_paper
from spacecraft.calibration_recording import fit_to_recording
from spacecraft.offline import fly_offline
from spacecraft.vehicle_config import VehicleConfig
from telemetry.mcap import write_mcap
from telemetry.recording import PassRecording

#: The law the pass is flown with (the defaults are 0.030 rad/s and 0.55; both with the
#: default 11 s rate filter and 0.035 deg dead band, which this fit leaves fixed).
TRUTH = {"bandwidth_radps": 0.04, "damping_ratio": 0.9}
#: Measured: the fit from the defaults recovers 0.03995 rad/s and 0.889 (seed 3): within
#: 0.2 % and 1.3 %; the vehicle's joint-servo lag and sensor noise make it inexact (the
#: prediction tracks ideally). The tolerances leave room for other seeds.
RELATIVE_TOLERANCE = {"bandwidth_radps": 0.03, "damping_ratio": 0.05}


@functools.cache
def ptp_plan() -> Plan:
    """A PTP A -> B with 60 s of settling (planned once, flown with each law; read only)."""
    return plan_ptp(DynamicsWorkspace(default_model()), PtpParams(settle_s=60.0))


def ptp_flown_with(law: dict[str, float], name: str) -> PassRecording:
    """A PTP A -> B with 60 s of settling, flown through the vehicle (seed 3) with ``law``."""
    workspace = DynamicsWorkspace(default_model())
    plan = ptp_plan()
    config = VehicleConfig(
        acs_gains=gains_from_parameters(workspace, law),
        initial_joints_rad=tuple(float(v) for v in plan.initial_joints_rad),
    )
    flight = fly_offline(plan, config, seed=3)
    return PassRecording.from_frames(name, plan, flight.epoch_ns, flight.frames)


@pytest.fixture(scope="module")
def flown() -> PassRecording:
    """The PTP flown with the TRUTH law."""
    return ptp_flown_with(TRUTH, "calibration")


@pytest.mark.slow
def test_fit_recovers_the_law_a_pass_was_flown_with(
    flown: PassRecording, workspace: DynamicsWorkspace, tmp_path: Path
) -> None:
    calls: list[tuple[int, int, float]] = []
    result = fit_to_recording(
        flown, ws=workspace, max_evaluations=40, progress=lambda *a: calls.append(a)
    )
    assert result.start == {"bandwidth_radps": 0.030, "damping_ratio": 0.55}
    for name, truth in TRUTH.items():
        assert result.parameters[name] == pytest.approx(truth, rel=RELATIVE_TOLERANCE[name])
    assert result.cost < 0.05 * result.cost_start
    assert result.standard_error is not None and set(result.standard_error) == set(TRUTH)
    assert all(math.isfinite(v) and v > 0 for v in result.standard_error.values())
    assert (
        [c[0] for c in calls]
        == list(range(1, len(calls) + 1))
        == list(range(1, result.evaluations + 1))
    )
    assert all(row.holds for row in result.targets)

    # the written [acs] file is the fit's law
    path = tmp_path / "acs.toml"
    write_acs_config(path, result.parameters)
    loaded = load_acs_config(workspace, path)
    fitted = gains_from_parameters(workspace, result.parameters)
    np.testing.assert_array_equal(loaded.kp_nm_per_rad, fitted.kp_nm_per_rad)
    np.testing.assert_array_equal(loaded.kd_nms_per_rad, fitted.kd_nms_per_rad)
    # (the filter was not fitted: the default's)
    assert not loaded.has_integral and loaded.rate_filter_tau_s == fitted.rate_filter_tau_s == 11.0


def test_written_config_with_filter_and_integral_loads(
    workspace: DynamicsWorkspace, tmp_path: Path
) -> None:
    values = {
        "bandwidth_radps": 0.05,
        "damping_ratio": 0.8,
        "rate_filter_tau_s": 2.5,
        "integral_time_s": 300.0,
        "torque_limit_nm": 0.04,
        "dead_band_deg": 0.03,
    }
    path = tmp_path / "acs.toml"
    write_acs_config(path, values)
    loaded = load_acs_config(workspace, path)
    want = gains_from_parameters(workspace, values)
    np.testing.assert_array_equal(loaded.ki_nm_per_rad_s, want.ki_nm_per_rad_s)
    assert loaded.rate_filter_tau_s == 2.5
    assert loaded.torque_limit_nm == want.torque_limit_nm == 0.04
    assert loaded.dead_band_rad == want.dead_band_rad == pytest.approx(math.radians(0.03))


@pytest.mark.slow
def test_paper_fit_reports_every_target(workspace: DynamicsWorkspace) -> None:
    # one evaluation (the start's): the rows are the start's, predicted and flown
    result = fit_to_paper(ws=workspace, max_evaluations=1, check_vehicle=True)
    assert result.evaluations == 1 and result.parameters == result.start
    ids = [row.id for row in result.targets]
    fitted = [
        "ptp_settling",
        "coordination_start",
        "coordination_feedback_min",
        "coordination_feedback_max",
        "coordination_feedforward_dip",
        "coordination_feedforward_overshoot",
        "coordination_offset_range",
        "coordination_offset_settling",
    ]
    assert ids == [*fitted, "gjm_base_pitch", "reactionless_grows_with_speed", *fitted]
    for row in result.targets[:8]:
        assert row.source == "prediction"
        assert isinstance(row.holds, bool) and isinstance(row.holds_start, bool)
        assert row.start is not None and row.fit is not None
    # the defaults are the calibrated law: every target the law shapes holds at the start,
    # predicted and flown (measured: PTP 105.5 / 100.5 s, starts within 0.049 / 0.036 deg,
    # (a) -0.355 / -0.351 and +0.491 / +0.502 deg, (b) dip -0.269 / -0.257 deg, overshoot
    # 0.201 / 0.199 deg over the next, (c)'s range 0.288 / 0.293 deg below the next and its
    # settling 17.5 / 12.3 s ahead of the next)
    predicted, flown = result.targets[:8], result.targets[10:]
    assert [row.holds_start for row in predicted] == [True] * 8, predicted
    assert [row.holds_start for row in flown] == [True] * 8, flown
    assert result.targets[9].holds is None  # not the law's: said so, never a pass
    # the vehicle flies what the prediction said, at the start: PTP settling within 5 %
    predicted, flown = result.targets[0], result.targets[10]
    assert flown.source == "vehicle" and flown.id == "ptp_settling"
    assert flown.start == pytest.approx(predicted.start, rel=0.05)
    assert result.cost <= result.cost_start
    json.dumps(result.to_dict())


def test_cli_refuses_unknown_parameters(tmp_path: Path) -> None:
    result = CliRunner().invoke(
        app, ["calibrate", "--parameters", "kp", "--out", str(tmp_path / "a.toml")]
    )
    assert result.exit_code == 2
    assert "kp" in result.output


#: The filter and the integral term, flown with the default bandwidth and damping (0.030
#: rad/s, 0.55) and fitted from the defaults (the calibrated 11 s filter, no integral term:
#: started at 1000 s, where a finite difference sees it). Measured (seed 3): tau 5.10 s (2 %)
#: and Ti 268 s (11 %) at evaluation 10, 4.92 s and 258 s at 13, left to converge 4.90 s and
#: 257 s (14 %: the integral term is the least observable in a 60 s settle) at 27. The whole
#: family fitted together (wn, zeta, tau, Ti: 30 evaluations) is bench/bench_calibration.py's.
FAMILY_TRUTH = {"rate_filter_tau_s": 5.0, "integral_time_s": 300.0}
FAMILY_TOLERANCE = {"rate_filter_tau_s": 0.15, "integral_time_s": 0.5}


@pytest.mark.slow
def test_fit_recovers_a_filtered_pid_law() -> None:
    workspace = DynamicsWorkspace(default_model())
    recording = ptp_flown_with(FAMILY_TRUTH, "family")
    result = fit_to_recording(recording, tuple(FAMILY_TRUTH), ws=workspace, max_evaluations=15)
    # from the defaults: the calibrated 11 s filter, no integral term
    assert result.start["rate_filter_tau_s"] == 11.0
    assert math.isinf(result.start["integral_time_s"])
    for name, truth in FAMILY_TRUTH.items():
        assert result.parameters[name] == pytest.approx(truth, rel=FAMILY_TOLERANCE[name])
    assert result.cost < 0.1 * result.cost_start  # measured: 0.065 against 2.04


#: A wheel torque limit that binds in the PTP (the default law asks for about 0.12 N m
#: there), flown with the default law otherwise. Measured (seed 3): 0.0394 N m (1.4 %) at
#: evaluation 3 and 0.0407 (1.7 %) from evaluation 5 on, from the default 0.3 N m, which does
#: not bind: the fit starts at 0.1 N m, where it does. Fitted together with wn and zeta (30
#: evaluations: 0.0402 N m, 0.0404 rad/s, 0.859) it is bench/bench_calibration.py's.
SATURATING_TRUTH = {"torque_limit_nm": 0.04}
SATURATING_TOLERANCE = {"torque_limit_nm": 0.05}


@pytest.mark.slow
def test_fit_recovers_a_wheel_torque_limit() -> None:
    workspace = DynamicsWorkspace(default_model())
    recording = ptp_flown_with(SATURATING_TRUTH, "saturating")
    result = fit_to_recording(recording, tuple(SATURATING_TRUTH), ws=workspace, max_evaluations=8)
    assert result.start["torque_limit_nm"] == 0.3
    for name, truth in SATURATING_TRUTH.items():
        assert result.parameters[name] == pytest.approx(truth, rel=SATURATING_TOLERANCE[name])
    assert result.cost < 0.01 * result.cost_start


@pytest.mark.slow
def test_cli_calibrates_to_a_stored_pass(
    flown: PassRecording, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("DATABASE_URL", raising=False)
    monkeypatch.setenv("HIKOBOSHI_DATA_DIR", str(tmp_path / "data"))
    mcap = tmp_path / "pass.mcap"
    write_mcap(flown, mcap)
    runner = CliRunner()
    imported = runner.invoke(app, ["mcap", "import", str(mcap)])
    assert imported.exit_code == 0, imported.output
    pass_id = re.findall(r"[0-9a-f-]{36}", imported.output)[0]
    out = tmp_path / "acs.toml"
    # the law alone: the servo fit and noise estimate of a recorded pass are
    # test_cli_calibrates_to_a_recorded_pass's
    args = ["calibrate", "--pass", pass_id, "--max-evaluations", "2", "--out", str(out)]
    result = runner.invoke(app, [*args, "--no-servo"])
    assert result.exit_code == 0, result.output
    assert out.read_text().startswith("[acs]\n")
    missing = runner.invoke(app, [*args[:2], "00000000-0000-4000-8000-000000000000", *args[3:]])
    assert missing.exit_code == 2 and "not found" in missing.output


# --- joint servos and sensor noise from a recorded pass ---------------------------------------

#: The servos and noise a pass is flown with: a lag and a bandwidth per joint, noise unlike
#: the defaults (0.005 deg, 0.0005 deg/s, 0.005 deg).
SERVO_LAG_S = (0.25, 0.15, 0.4, 0.6, 0.2, 0.35)
SERVO_BANDWIDTH_RADPS = (6.0, 5.0, 7.0, 6.0, 8.0, 4.0)
NOISE_DEG = {"attitude_rad": 0.008, "rate_radps": 0.001, "joint_rad": 0.003}


def servo_flown(settle_s: float, name: str) -> PassRecording:
    """A PTP from A to a pose that moves every joint (28 s), ``settle_s`` of settling, flown
    through the vehicle with SERVO_* and NOISE_DEG (seed 5)."""
    from planner.simulation import SimConfig, default_servo_gains
    from spacecraft.vehicle_config import SensorNoise

    workspace = DynamicsWorkspace(default_model())
    goal = (20.0, 15.0, -20.0, 30.0, 25.0, 40.0)
    plan = plan_ptp(workspace, PtpParams(goal_joints_deg=goal, settle_s=settle_s))
    servo = default_servo_gains(
        workspace.model, bandwidth_radps=SERVO_BANDWIDTH_RADPS, lag_s=SERVO_LAG_S
    )
    config = VehicleConfig(
        sim=SimConfig(gravity_gradient=True, servo=servo),
        noise=SensorNoise(**{k: math.radians(v) for k, v in NOISE_DEG.items()}),
        initial_joints_rad=tuple(float(v) for v in plan.initial_joints_rad),
    )
    flight = fly_offline(plan, config, seed=5)
    return PassRecording.from_frames(name, plan, flight.epoch_ns, flight.frames)


@pytest.fixture(scope="module")
def servo_pass() -> PassRecording:
    """The servo fit's pass: 10 s of settling (the servos show while the joints move and
    stop; each of the fit's arm simulations flies the whole plan, so a long hold only costs)."""
    return servo_flown(10.0, "servo")


@pytest.fixture(scope="module")
def noise_pass() -> PassRecording:
    """The noise estimate's pass: 40 s of settling (the holds it reads)."""
    return servo_flown(40.0, "noise")


@pytest.mark.slow
def test_servo_fit_recovers_each_joint_s_lag_and_bandwidth(
    servo_pass: PassRecording, workspace: DynamicsWorkspace
) -> None:
    from spacecraft.servo_fit import fit_servo

    calls: list[int] = []
    # three optimiser steps on the arm (40 simulations; left to converge, 79: the default
    # budget of 20 stops at 6, with the same figures but joint 5's 7.86 rad/s)
    fit = fit_servo(servo_pass, workspace, max_evaluations=3, progress=calls.append)
    assert calls == list(range(1, fit.evaluations + 1))
    # Measured (seed 5; the same with 40 s of settling): every lag within 0.1 % (0.2502,
    # 0.1502, 0.4001, 0.6002, 0.2000, 0.3500 s); bandwidths 5.92, 5.05, -, 6.11, 7.76, 3.97
    # rad/s (1 to 3 %). Joint 3's
    # (0.4 s at 7 rad/s, damping ratio 1.4) is not observable: its standard error is 2.2 rad/s,
    # over the 10 % the fit accepts, and the start's 6 rad/s is kept, said in its note.
    for joint, lag, bandwidth in zip(fit.joints, SERVO_LAG_S, SERVO_BANDWIDTH_RADPS, strict=True):
        assert joint.lag_s == pytest.approx(lag, rel=0.02), joint
        assert joint.lag_standard_error_s is not None and joint.lag_standard_error_s < 0.01
        if joint.bandwidth_radps is not None:
            assert joint.bandwidth_radps == pytest.approx(bandwidth, rel=0.06), joint
        else:
            assert "not observable" in joint.note
        # the start (ETS-VII's servos) tracks worse than the fit; the fit down to the 0.003 deg
        # encoder noise (measured 0.0028 to 0.0031 deg)
        assert joint.rms_fit_deg is not None and joint.rms_start_deg is not None
        assert joint.rms_fit_deg < 0.0035 and joint.rms_fit_deg <= joint.rms_start_deg
    assert sum(j.bandwidth_radps is not None for j in fit.joints) >= 4


def test_sensor_noise_is_estimated_from_the_holds(noise_pass: PassRecording) -> None:
    from spacecraft.servo_fit import estimate_sensor_noise

    noise = estimate_sensor_noise(noise_pass)
    # Measured: 0.00815 deg, 0.00101 deg/s, 0.00308 deg from about 1000 second differences
    # per axis in the 35 s of settling used (2 to 3 % off; the estimate's own spread is
    # about 1 / sqrt(2 N) ~ 2 %).
    assert noise.attitude_deg == pytest.approx(NOISE_DEG["attitude_rad"], rel=0.1)
    assert noise.rate_degps == pytest.approx(NOISE_DEG["rate_radps"], rel=0.1)
    assert noise.joint_deg == pytest.approx(NOISE_DEG["joint_rad"], rel=0.1)
    assert min(noise.samples.values()) > 500


@pytest.mark.slow
def test_cli_calibrates_to_a_recorded_pass(
    flown: PassRecording, workspace: DynamicsWorkspace, tmp_path: Path
) -> None:
    """The recorded pass of the law's tests (ETS-VII's servos, default noise), one run: the
    [acs] file is the fitted law's, --json prints the report; --vehicle-out holds [servo] and
    [sensor_noise] tables that load as a robot description's, and the spacecraft's
    --vehicle-config flies them."""
    from hikoboshi.spacecraft_cli import _with_vehicle_tables
    from planner.description import load_vehicle_tables
    from planner.simulation import ETS7_SERVO_LAG_S

    mcap = tmp_path / "pass.mcap"
    write_mcap(flown, mcap)
    out, report, vehicle = tmp_path / "acs.toml", tmp_path / "r.json", tmp_path / "vehicle.toml"
    args = ["calibrate", "--mcap", str(mcap), "--max-evaluations", "4", "--out", str(out)]
    args += ["--report", str(report), "--vehicle-out", str(vehicle), "--json"]
    # a budget of one optimiser evaluation of the arm (12 simulations: the start's tracking,
    # the evaluation and its Jacobian): the joint-by-joint lags it starts from are within
    # 0.5 % of ETS-VII's (measured); the arm fit's convergence is
    # test_servo_fit_recovers_each_joint_s_lag_and_bandwidth's
    result = CliRunner().invoke(app, [*args, "--servo-max-evaluations", "1"])
    assert result.exit_code == 0, result.output
    doc = json.loads(report.read_text())
    # --json: the report's fields and the files written, on stdout (progress is on stderr)
    printed = json.loads(result.stdout)
    assert printed.pop("wrote") == [str(out), str(report), str(vehicle)]
    assert printed == doc
    assert doc["kind"] == "recording" and doc["evaluations"] <= 4
    # the [acs] file is the fitted law's
    loaded = load_acs_config(workspace, out)
    fitted = gains_from_parameters(workspace, doc["parameters"])
    np.testing.assert_array_equal(loaded.kp_nm_per_rad, fitted.kp_nm_per_rad)
    assert "[acs]" in out.read_text() and "bandwidth_radps" in out.read_text()
    ids = {row["id"] for row in doc["targets"]}
    assert "rms_residual_y_deg" in ids
    # the servos and the noise
    tables = load_vehicle_tables(vehicle, 6)
    assert tables.servo is not None and tables.sensor_noise is not None
    lags = np.asarray(tables.servo.lag_s)
    # A->B moves joints 1 to 4 and 6 (fitted: within 2 % of ETS-VII's lags); joint 5 stays
    # at 0 and keeps its start value.
    np.testing.assert_allclose(lags, ETS7_SERVO_LAG_S, rtol=0.02)
    assert tables.sensor_noise.attitude_rad == pytest.approx(math.radians(0.005), rel=0.1)
    assert {"servo_lag_j4_s", "servo_bandwidth_j4_radps", "sensor_noise_joint"} <= ids
    assert doc["servo"]["joints"][4]["note"].startswith("commanded at under")
    assert doc["sensor_noise"]["samples"]["joint"] > 100
    flying = _with_vehicle_tables(VehicleConfig(), vehicle)
    np.testing.assert_allclose(
        flying.sim.servo.kd_nms_per_rad / flying.sim.servo.kp_nm_per_rad, lags, rtol=1e-12
    )
    assert flying.noise.joint_rad == tables.sensor_noise.joint_rad
    # without a recorded pass there are no servos to write
    refused = CliRunner().invoke(app, ["calibrate", "--out", str(out), "--vehicle-out", "v.toml"])
    assert refused.exit_code == 2 and "--vehicle-out needs a recorded pass" in refused.output
