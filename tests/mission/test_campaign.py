"""The campaign planner (server/operations/campaign.py over mission/campaign.py): each pass in the
first window after the one before, fitting its net time; each pass starting where the one
before left the vehicle plus the gap; the gap's gravity-gradient momentum against an
independent integration (plain sgp4 radii every second, the textbook torque, the reference
dynamics' inertia); the files written and read back; the refusals naming pass and quantity.
"""

from __future__ import annotations

import json
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np
import pytest
from sgp4.api import jday

from hikoboshi.campaign_cli import write_campaign
from mission import MISSIONS_DIR, compute_windows, load_mission
from mission.campaign import load_campaign
from planner.frames import matrix_from_quat_xyzw
from planner.plan import Plan
from server.operations.campaign import Campaign, CampaignInfeasible, plan_campaign
from server.operations.campaign_gap import GRAVITY_MU_M3PS2
from tests.reference_dynamics import forward_kinematics, subtree_composites
from tests.support.orbits import mission_doc, satrec

ETS7 = MISSIONS_DIR / "ets7-1999.toml"
START = datetime(1999, 9, 30, tzinfo=UTC)
#: Cheap passes (the default assignment is the command line's test): three, so the chain
#: is checked across two gaps.
ASSIGNMENT = (("ptp",), ("nonholonomic",), ("ptp",))
#: The gap momentum against the independent integration (N m s; about 1 N m s is loaded
#: in a 30-minute gap; measured difference: under 1e-9 over 30 and 60 minutes).
TOLERANCE_NMS = 1e-4


@pytest.fixture(scope="module")
def campaign() -> Campaign:
    return plan_campaign(load_mission(ETS7), START, assignment=ASSIGNMENT)


def independent_gravity_gradient_nms(
    start: datetime, end: datetime, inertia_kgm2: np.ndarray
) -> np.ndarray:
    """``sum 3 mu / r^3 (r_hat x I r_hat) dt`` by the trapezoid rule every second, ``r``
    from plain sgp4, the base Earth-pointing (the Earth's centre along base +z)."""
    sat = satrec(mission_doc())
    span_s = (end - start).total_seconds()
    n = int(np.ceil(span_s))
    offsets = np.linspace(0.0, span_s, n + 1)
    jd0, fr0 = jday(start.year, start.month, start.day, start.hour, start.minute, 0.0)
    fr0 += (start.second + start.microsecond * 1e-6) / 86400.0
    radii = []
    for s in offsets:
        error, r_km, _ = sat.sgp4(jd0, fr0 + s / 86400.0)
        assert error == 0
        radii.append(np.linalg.norm(r_km) * 1000.0)
    f = 3.0 * 3.986004418e14 / np.array(radii) ** 3
    integral = float(np.sum((f[1:] + f[:-1]) * 0.5 * np.diff(offsets)))
    r_hat = np.array([0.0, 0.0, 1.0])
    return integral * np.cross(r_hat, inertia_kgm2 @ r_hat)


def reference_inertia_kgm2(joints_rad: np.ndarray) -> np.ndarray:
    """The whole system's inertia about its centre of mass, base frame, from the reference
    dynamics (tests/reference_dynamics.py, not MuJoCo)."""
    kin = forward_kinematics(joints_rad, np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(3))
    whole, _ = subtree_composites(kin)
    return np.asarray(whole.inertia_com_orbit_kgm2)


@pytest.mark.slow
def test_each_pass_takes_the_first_window_after_the_last_and_fits_its_net_time(
    campaign: Campaign,
) -> None:
    windows = compute_windows(load_mission(ETS7), START, 24.0)
    previous_end = START
    assert [p.experiments for p in campaign.passes] == list(ASSIGNMENT)
    for p in campaign.passes:
        w = p.window
        assert w.net_start_utc >= previous_end
        earlier = [
            x
            for x in windows
            if previous_end <= x.net_start_utc < w.net_start_utc and x.net_s > 0.0
        ]
        assert earlier == [], f"pass {p.index} skipped {earlier}"
        assert p.plan_start_utc == w.net_start_utc + timedelta(seconds=campaign.start_lead_s)
        assert p.plan_end_utc <= w.net_end_utc
        assert p.plan.duration_s + campaign.start_lead_s <= w.net_s
        assert p.flight_rules is not None and p.flight_rules.passed
        assert p.flight_rules.row("fits_pass").limit == pytest.approx(
            w.net_s - campaign.start_lead_s
        )
        previous_end = p.plan_end_utc


@pytest.mark.slow
def test_each_pass_starts_where_the_last_ended_plus_the_gap(campaign: Campaign) -> None:
    first = campaign.passes[0]
    np.testing.assert_array_equal(first.start_state.wheel_momentum_nms, np.zeros(3))
    np.testing.assert_array_equal(first.gap_momentum_nms, np.zeros(3))
    for before, after in zip(campaign.passes, campaign.passes[1:], strict=False):
        end, start = before.end_state, after.start_state
        np.testing.assert_array_equal(start.joints_rad, end.joints_rad)
        np.testing.assert_allclose(
            start.wheel_momentum_nms,
            end.wheel_momentum_nms + after.gap_momentum_nms,
            rtol=0,
            atol=1e-12,
        )
        # attitude control holds the nominal attitude in the gap; the base at rest
        np.testing.assert_array_equal(start.quat_orbit_from_base_xyzw, [0.0, 0.0, 0.0, 1.0])
        np.testing.assert_array_equal(start.omega_base_orbit_radps, np.zeros(3))
        assert after.gap_s == pytest.approx(
            (after.plan_start_utc - before.plan_end_utc).total_seconds()
        )
        assert after.gap_s > 600.0
        # the plan itself starts there: its joints and the wheel momentum it predicts from
        np.testing.assert_array_equal(after.plan.initial_joints_rad, end.joints_rad)
        np.testing.assert_array_equal(
            after.plan.prediction.wheel_momentum_nms[0], start.wheel_momentum_nms
        )
        # and its end state is its prediction's last row
        np.testing.assert_array_equal(
            after.end_state.wheel_momentum_nms, after.plan.prediction.wheel_momentum_nms[-1]
        )


@pytest.mark.slow
def test_the_gap_momentum_matches_an_independent_integration(campaign: Campaign) -> None:
    for before, after in zip(campaign.passes, campaign.passes[1:], strict=False):
        end = before.end_state
        inertia = reference_inertia_kgm2(end.joints_rad)
        loaded = independent_gravity_gradient_nms(
            before.plan_end_utc, after.plan_start_utc, inertia
        )
        assert np.linalg.norm(loaded) > 0.3  # a real load over a 10-50 minute gap
        assert abs(loaded[2]) < 1e-12  # eq. (13): never about yaw, Earth-pointing
        np.testing.assert_allclose(
            after.gap_gravity_gradient_nms, loaded, rtol=0, atol=TOLERANCE_NMS
        )
        # the base's residual rate settles into the wheels, momentum kept (orbit frame)
        rot = matrix_from_quat_xyzw(end.quat_orbit_from_base_xyzw)
        settled = rot @ (inertia @ (rot.T @ end.omega_base_orbit_radps) + end.wheel_momentum_nms)
        np.testing.assert_allclose(
            after.start_state.wheel_momentum_nms, settled + loaded, rtol=0, atol=TOLERANCE_NMS
        )


def test_the_gravity_gradient_uses_the_real_orbit_not_a_constant_radius() -> None:
    """The mean-elements orbit is near-circular: the radius varies, and the loaded momentum
    follows it (against the SPEC's 550 km circle it differs by the radius's cube)."""
    from mission.campaign import orbit_radius_m
    from server.operations.campaign_gap import gravity_gradient_momentum_nms

    mission = load_mission(ETS7)
    inertia = reference_inertia_kgm2(np.zeros(6))
    t1 = START + timedelta(hours=1)
    got = gravity_gradient_momentum_nms(mission, START, t1, inertia)
    want = independent_gravity_gradient_nms(START, t1, inertia)
    np.testing.assert_allclose(got, want, rtol=1e-6)
    radii = orbit_radius_m(mission, [START + timedelta(seconds=s) for s in range(0, 3600, 60)])
    assert radii.max() - radii.min() > 1000.0  # eccentricity 0.0005: +-3.5 km
    circle = 3.0 * GRAVITY_MU_M3PS2 / (6378.137e3 + 550e3) ** 3 * 3600.0
    r_hat = np.array([0.0, 0.0, 1.0])
    constant = circle * np.cross(r_hat, inertia @ r_hat)
    assert not np.allclose(got, constant, rtol=1e-3)


@pytest.mark.slow
def test_the_files_are_plans_and_read_back(campaign: Campaign, tmp_path: Path) -> None:
    path = write_campaign(campaign, tmp_path)
    assert path == tmp_path / "campaign.json"
    record = load_campaign(path)
    assert record.mission == "ets7-1999"
    assert record.robot == campaign.passes[0].plan.robot
    assert len(record.passes) == len(campaign.passes)
    for p, r in zip(campaign.passes, record.passes, strict=True):
        assert r.index == p.index and r.experiments == p.experiments
        assert r.window.relay == p.window.relay
        assert abs((r.window.aos_utc - p.window.aos_utc).total_seconds()) < 0.001
        assert abs((r.window.net_start_utc - p.window.net_start_utc).total_seconds()) < 0.002
        plan = Plan.from_json(r.plan_path.read_text())
        np.testing.assert_array_equal(plan.command_joints_rad, p.plan.command_joints_rad)
        assert plan.flight_rules is not None and plan.flight_rules["rows"]
        for name in ("joints_rad", "wheel_momentum_nms", "quat_orbit_from_base_xyzw"):
            np.testing.assert_array_equal(
                getattr(r.start_state, name), getattr(p.start_state, name)
            )
            np.testing.assert_array_equal(getattr(r.end_state, name), getattr(p.end_state, name))
        np.testing.assert_array_equal(r.gap_momentum_nms, p.gap_momentum_nms)
    doc = json.loads(path.read_text())
    window = doc["passes"][1]["window"]
    assert {"relay", "aos_utc", "los_utc", "net_start_utc", "net_end_utc"} <= window.keys()
    assert 0.2 < window["light_time_min_s"] <= window["light_time_max_s"] < 0.3


def test_an_unknown_experiment_is_refused_naming_its_pass() -> None:
    with pytest.raises(CampaignInfeasible, match=r"pass 2: unknown experiment 'warp'"):
        plan_campaign(load_mission(ETS7), START, assignment=[["ptp"], ["warp"]])
    with pytest.raises(CampaignInfeasible, match=r"pass 1: no experiment"):
        plan_campaign(load_mission(ETS7), START, assignment=[[]])


def _mission_with(tmp_path: Path, old: str, new: str) -> Path:
    text = ETS7.read_text()
    assert old in text
    path = tmp_path / "variant.toml"
    path.write_text(text.replace(old, new))
    return path


def test_no_window_in_range_is_refused_naming_the_pass(tmp_path: Path) -> None:
    # a line of sight that must clear 2000 km never does from 550 km: no window at all
    path = _mission_with(tmp_path, "grazing_height_km = 100.0", "grazing_height_km = 2000.0")
    with pytest.raises(CampaignInfeasible, match=r"pass 1: no window's net time starts"):
        plan_campaign(load_mission(path), START, check_rules=False)


def test_a_plan_longer_than_its_window_is_refused_naming_pass_and_times(tmp_path: Path) -> None:
    # margins that leave about a minute of the first window (57.7 min)
    path = _mission_with(tmp_path, "aos_margin_s = 120.0", "aos_margin_s = 1800.0")
    path.write_text(path.read_text().replace("los_margin_s = 60.0", "los_margin_s = 1600.0"))
    with pytest.raises(CampaignInfeasible, match=r"pass 1 \(TDRS-West, AOS .*\): the plan") as e:
        plan_campaign(load_mission(path), START, assignment=[["ptp"]], check_rules=False)
    assert "start lead" in str(e.value) and " s" in str(e.value)


@pytest.mark.slow
def test_the_ground_replans_a_pass_from_its_plan_s_parameters_alone(campaign: Campaign) -> None:
    """POST /api/plans with experiment "pass" and the plan file's parameters: the start
    state and the orbit travel in them, so the ground's plan is the campaign's."""
    from server.operations.plans import plan_request
    from server.schemas.plans import PlanCreate

    mine = campaign.passes[1].plan
    parameters = json.loads(json.dumps(mine.parameters))
    assert parameters["start_wheel_momentum_nms"] != [0.0, 0.0, 0.0]
    assert parameters["gravity_gradient_radius_m"] > 6.9e6
    theirs = plan_request(PlanCreate(experiment="pass", parameters=parameters))
    np.testing.assert_array_equal(theirs.command_joints_rad, mine.command_joints_rad)
    np.testing.assert_allclose(
        theirs.prediction.wheel_momentum_nms, mine.prediction.wheel_momentum_nms, atol=1e-12
    )
    np.testing.assert_array_equal(
        theirs.prediction.wheel_momentum_nms[0], campaign.passes[1].start_state.wheel_momentum_nms
    )
    assert theirs.flight_rules is not None and theirs.flight_rules["passed"]
