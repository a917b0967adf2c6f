"""Live limits as data (planner.limits): the [limits] table's parsing and its refusals, bands
and their classification, and the live clearance watch's skipped values against computing
every pair every time."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from planner.clearance_watch import ClearanceWatch
from planner.collision import body_poses
from planner.description import EXAMPLES_DIR, InvalidRobotDescription, default_robot, load_robot
from planner.errors import InvalidInput
from planner.limits import (
    DEFAULT_LIMITS,
    QUANTITIES,
    RED,
    SEVERITY_RANK,
    Bands,
    Limits,
    Severity,
    channel_names,
)
from planner.robot import RobotDescription


@pytest.fixture(scope="module")
def ets7() -> RobotDescription:
    return default_robot()


# --- the catalogue and the defaults --------------------------------------------------------


def test_the_catalogue_names_the_design_s_quantities() -> None:
    assert list(QUANTITIES) == [
        "attitude_error_deg",
        "body_rate_degps",
        "wheel_momentum_fraction",
        "wheel_speed_rpm",
        "joint_tracking_error_deg",
        "joint_limit_distance_deg",
        "clearance_m",
        "schedule_occupancy",
        "frames_behind",
        "frame_age_s",
    ]
    safing = {name for name, q in QUANTITIES.items() if q.safing}
    assert safing == {
        "attitude_error_deg",
        "wheel_momentum_fraction",
        "joint_tracking_error_deg",
        "clearance_m",
    }
    low = {name for name, q in QUANTITIES.items() if q.direction == "low"}
    assert low == {"joint_limit_distance_deg", "clearance_m"}
    assert [s.value for s in sorted(Severity, key=SEVERITY_RANK.__getitem__)] == [
        "watch",
        "warning",
        "distress",
        "critical",
        "severe",
    ]
    assert RED is Severity.CRITICAL


def test_defaults_cover_every_quantity_and_every_safing_quantity_has_a_red_limit() -> None:
    assert set(DEFAULT_LIMITS.bands) == set(QUANTITIES)
    assert set(DEFAULT_LIMITS.safing_limits()) == {
        name for name, q in QUANTITIES.items() if q.safing
    }
    # the brief's red limits: tracking error crossed within seconds by a stuck joint at
    # 2.7 deg/s, SPEC 8's 2.0 deg excursion plus margin, 0.9 of wheel capacity (SPEC: 0.8
    # predicted), well below the 0.10 m predicted clearance
    red = DEFAULT_LIMITS.safing_limits()
    assert red["attitude_error_deg"] > 2.0
    assert red["wheel_momentum_fraction"] == pytest.approx(0.9)
    assert red["clearance_m"] < 0.10
    assert red["joint_tracking_error_deg"] / 2.7 < 5.0  # seconds to cross at 2.7 deg/s


def test_channel_names() -> None:
    assert channel_names("attitude_error_deg", 6, 3) == ("x", "y", "z")
    assert channel_names("joint_tracking_error_deg", 7, 3) == tuple(
        f"joint{i}" for i in range(1, 8)
    )
    assert channel_names("wheel_speed_rpm", 6, 3) == ("wheel1", "wheel2", "wheel3")
    assert channel_names("clearance_m", 6, 3) == ("",)
    with pytest.raises(InvalidInput, match="unknown quantity 'speed'"):
        channel_names("speed", 6, 3)


# --- bands ---------------------------------------------------------------------------------


def test_high_bands_classify_at_or_above_each_threshold() -> None:
    bands = Bands(
        "joint_tracking_error_deg",
        ((Severity.WATCH, 2.0), (Severity.WARNING, 3.0), (Severity.SEVERE, 8.0)),
    )
    assert bands.classify(1.999) is None
    assert bands.classify(2.0) is Severity.WATCH
    assert bands.classify(2.5) is Severity.WATCH
    assert bands.classify(3.0) is Severity.WARNING
    assert bands.classify(7.9) is Severity.WARNING
    assert bands.classify(8.0) is Severity.SEVERE
    assert bands.classify(math.inf) is Severity.SEVERE
    assert bands.classify(math.nan) is None
    assert bands.red() == (Severity.SEVERE, 8.0)
    assert bands.threshold(Severity.WARNING) == 3.0
    assert bands.threshold(Severity.DISTRESS) is None


def test_low_bands_classify_at_or_below_each_threshold() -> None:
    bands = Bands(
        "clearance_m", ((Severity.WATCH, 0.08), (Severity.WARNING, 0.06), (Severity.CRITICAL, 0.03))
    )
    assert bands.classify(0.0801) is None
    assert bands.classify(0.08) is Severity.WATCH
    assert bands.classify(0.05) is Severity.WARNING
    assert bands.classify(0.03) is Severity.CRITICAL
    assert bands.classify(-0.2) is Severity.CRITICAL
    assert bands.red() == (Severity.CRITICAL, 0.03)
    assert bands.least == 0.08


def test_classify_array_is_classify_of_each_element() -> None:
    rng = np.random.default_rng(3)
    for name in ("wheel_momentum_fraction", "joint_limit_distance_deg"):
        bands = DEFAULT_LIMITS[name]
        edges = np.array([t for _, t in bands.thresholds])
        values = np.concatenate([rng.uniform(-1.0, 2.0 * edges.max(), 500), edges, [np.nan]])
        ranks = bands.classify_array(values.reshape(-1, 1))[:, 0]
        expected = [bands.classify(v) for v in values]
        assert [None if r == 0 else list(SEVERITY_RANK)[r - 1] for r in ranks] == expected
        assert ranks.max() > 0 and ranks.min() == 0  # both within and beyond were drawn


def test_a_band_without_red_has_no_red() -> None:
    assert DEFAULT_LIMITS["body_rate_degps"].red() is None
    assert "body_rate_degps" not in DEFAULT_LIMITS.safing_limits()


# --- tables --------------------------------------------------------------------------------


def test_a_table_replaces_the_quantities_it_names_and_keeps_the_defaults_of_the_rest() -> None:
    limits = Limits.from_table(
        {"clearance_m": {"watch": 0.2, "severe": 0.01}, "frame_age_s": {"distress": 30}}
    )
    assert limits["clearance_m"].thresholds == (
        (Severity.WATCH, 0.2),
        (Severity.SEVERE, 0.01),
    )
    assert limits["frame_age_s"].to_dict() == {"distress": 30.0}
    assert limits["attitude_error_deg"] == DEFAULT_LIMITS["attitude_error_deg"]
    assert limits.safing_limits()["clearance_m"] == 0.01
    assert Limits.from_table(limits.to_table()) == limits
    assert Limits.from_table({}) == DEFAULT_LIMITS


TABLE_FAULTS: dict[str, tuple[dict[str, object], list[str]]] = {
    "unknown_quantity": ({"wheel_temperature": {"watch": 1.0}}, ["unknown quantity"]),
    "unknown_severity": (
        {"clearance_m": {"yellow": 0.08}},
        ["[limits.clearance_m]", "unknown severity yellow", "watch, warning"],
    ),
    "empty": ({"clearance_m": {}}, ["[limits.clearance_m]", "empty"]),
    "not_a_table": ({"clearance_m": 0.08}, ["[limits.clearance_m]", "must be a table"]),
    "nan": ({"body_rate_degps": {"watch": math.nan}}, ["watch must be finite"]),
    "inf": ({"body_rate_degps": {"warning": math.inf}}, ["warning must be finite"]),
    "text": ({"body_rate_degps": {"watch": "0.1"}}, ["watch must be a number"]),
    "bool": ({"body_rate_degps": {"watch": True}}, ["watch must be a number"]),
    "zero_high": ({"frames_behind": {"watch": 0}}, ["watch = 0 must be > 0"]),
    "high_out_of_order": (
        {"joint_tracking_error_deg": {"watch": 3.0, "critical": 2.0}},
        ["critical = 2.0 must be strictly above watch = 3.0"],
    ),
    "high_equal": (
        {"joint_tracking_error_deg": {"watch": 3.0, "warning": 3.0}},
        ["warning = 3.0 must be strictly above watch = 3.0"],
    ),
    "low_out_of_order": (
        {"clearance_m": {"watch": 0.03, "critical": 0.08}},
        ["critical = 0.08 must be strictly below watch = 0.03"],
    ),
    "persistence_zero": ({"persistence": 0}, ["[limits].persistence", "from 1 to 1000, got 0"]),
    "persistence_text": ({"persistence": "3"}, ["[limits].persistence", "got '3'"]),
    "persistence_float": ({"persistence": 2.5}, ["[limits].persistence", "got 2.5"]),
    "persistence_bool": ({"persistence": True}, ["[limits].persistence", "got True"]),
    "persistence_huge": ({"persistence": 1001}, ["[limits].persistence", "got 1001"]),
}


def test_a_table_s_persistence_is_kept_and_defaults_to_one() -> None:
    limits = Limits.from_table({"persistence": 3, "frame_age_s": {"distress": 30}})
    assert limits.persistence == 3 and DEFAULT_LIMITS.persistence == 1
    assert limits["frame_age_s"].to_dict() == {"distress": 30.0}
    assert Limits.from_table(limits.to_table()) == limits
    assert "persistence" not in DEFAULT_LIMITS.to_table()  # 1: the tables of before


@pytest.mark.parametrize("fault", list(TABLE_FAULTS))
def test_a_bad_table_is_refused_with_the_reason(fault: str) -> None:
    table, fragments = TABLE_FAULTS[fault]
    with pytest.raises(InvalidInput) as info:
        Limits.from_table(table)
    for fragment in fragments:
        assert fragment in str(info.value), str(info.value)


# --- the description's [limits] ------------------------------------------------------------


def _copy(tmp_path: Path, name: str) -> Path:
    target = tmp_path / name
    shutil.copytree(EXAMPLES_DIR / name, target)
    return target / f"{name}.toml"


def _set_limits(toml: Path, table: str) -> None:
    """``toml`` with its [limits] tables replaced by ``table`` (a top-level key first)."""
    text = toml.read_text()
    head = text.split("[limits.", 1)[0]
    if table.startswith("limits ="):
        toml.write_text(table + head)
    else:
        toml.write_text(head + table)


def test_the_shipped_robots_give_every_quantity(ets7: RobotDescription) -> None:
    orihime = load_robot(EXAMPLES_DIR / "orihime" / "orihime.toml")
    for robot in (ets7, orihime):
        text = robot.path.read_text()
        for name in QUANTITIES:
            assert f"[limits.{name}]" in text, (robot.name, name)
    assert ets7.limits == DEFAULT_LIMITS  # the defaults are ETS-VII's


def test_a_description_s_limits_are_read_and_the_rest_default(tmp_path: Path) -> None:
    toml = _copy(tmp_path, "ets7")
    _set_limits(toml, "[limits.clearance_m]\nwatch = 0.2\ncritical = 0.05\n")
    robot = load_robot(toml)
    assert robot.limits["clearance_m"].to_dict() == {"watch": 0.2, "critical": 0.05}
    assert robot.limits["frame_age_s"] == DEFAULT_LIMITS["frame_age_s"]
    assert robot.content_sha256 != default_robot().content_sha256
    assert robot.limits.persistence == 1


def test_a_description_s_persistence_is_read(tmp_path: Path) -> None:
    toml = _copy(tmp_path, "ets7")
    _set_limits(toml, "[limits]\npersistence = 4\n[limits.clearance_m]\nwatch = 0.2\n")
    robot = load_robot(toml)
    assert robot.limits.persistence == 4
    assert robot.limits["clearance_m"].to_dict() == {"watch": 0.2}


@pytest.mark.parametrize(
    ("table", "fragments"),
    [
        ("[limits.clearance_m]\nyellow = 0.1\n", ["[limits.clearance_m]", "unknown severity"]),
        ("[limits.hand_speed]\nwatch = 0.1\n", ["[limits.hand_speed]", "unknown quantity"]),
        (
            "[limits.attitude_error_deg]\nwatch = 3.0\nwarning = 2.0\n",
            ["[limits.attitude_error_deg]", "strictly above"],
        ),
        ("[limits]\nclearance_m = 0.1\n", ["[limits.clearance_m]", "must be a table"]),
        ("limits = 3\n", ["[limits]", "must be a table"]),
        ("[limits]\npersistence = 0\n", ["[limits].persistence", "from 1 to 1000"]),
    ],
)
def test_a_bad_limits_table_names_the_file_and_the_element(
    tmp_path: Path, table: str, fragments: list[str]
) -> None:
    toml = _copy(tmp_path, "ets7")
    _set_limits(toml, table)
    with pytest.raises(InvalidRobotDescription) as info:
        load_robot(toml)
    message = str(info.value)
    assert message.startswith(str(toml)), message
    for fragment in fragments:
        assert fragment in message, message


# --- the live clearance --------------------------------------------------------------------


def _random_motion(rng: np.random.Generator, steps: int, start: np.ndarray) -> np.ndarray:
    """A smooth random joint path (rate up to a few deg per step) with sensor-like noise."""
    rate = np.cumsum(rng.normal(0.0, 0.002, (steps, start.size)), axis=0)
    rate = np.clip(rate, -0.05, 0.05)
    path = start + np.cumsum(rate, axis=0)
    return path + rng.normal(0.0, np.radians(0.005), path.shape)


def test_poses_are_the_flight_rules_poses(ets7: RobotDescription) -> None:
    watch = ClearanceWatch(ets7, 0.08)
    q = np.random.default_rng(1).uniform(-2.0, 2.0, (6, 6))
    R, t = body_poses(ets7.model, q)
    for i in range(q.shape[0]):
        r_i, t_i = watch._poses(q[i])
        np.testing.assert_allclose(r_i, R[i], atol=1e-14)
        np.testing.assert_allclose(t_i, t[i], atol=1e-14)


def test_each_pair_moves_no_faster_than_its_lever(ets7: RobotDescription) -> None:
    """The bound the watch skips on: d_p(q') >= d_p(q) - sum_k C[p, k] |q'_k - q_k|."""
    watch = ClearanceWatch(ets7, 0.08)
    rng = np.random.default_rng(7)
    b = ets7.pose_joints_rad("B")
    worst_ratio = 0.0
    for _ in range(40):
        q = rng.uniform(-1.0, 1.0, 6) + b * rng.uniform(0.0, 1.0)
        step = rng.normal(0.0, 0.05, 6) * (rng.uniform(size=6) < 0.6)
        d0, d1 = watch.pair_distances_m(q), watch.pair_distances_m(q + step)
        allowed = watch.lever @ np.abs(step)
        assert np.all(d0 - d1 <= allowed + 1e-6)
        moving = allowed > 1e-9
        worst_ratio = max(worst_ratio, float(np.max((d0 - d1)[moving] / allowed[moving])))
    assert worst_ratio > 0.1  # the bound is not vacuous: some pair uses a good part of it


def test_skipped_values_are_honest_against_every_pair_every_time(ets7: RobotDescription) -> None:
    """On a random motion that comes near and into contact, in batches and one by one: every
    value is a lower bound of the exact clearance, exact whenever it is at or below the
    threshold, so that its band is always the exact clearance's band; and most calls ask
    coal for few pairs or none."""
    bands = DEFAULT_LIMITS["clearance_m"]
    threshold = bands.least
    rng = np.random.default_rng(11)
    path = _random_motion(rng, 600, ets7.pose_joints_rad("B"))
    watch = ClearanceWatch(ets7, threshold)
    reference = ClearanceWatch(ets7, threshold)
    got = np.concatenate([watch.clearances_m(path[i : i + 7]) for i in range(0, 600, 7)])
    exact = np.array([reference.exact_m(q) for q in path])
    assert exact.min() < 0.03 < threshold < exact.max()  # the motion crosses every band
    assert np.all(got <= exact + 1e-9)
    near = got <= threshold
    np.testing.assert_allclose(got[near], exact[near], atol=1e-12)
    assert np.array_equal(near, exact <= threshold)
    assert [bands.classify(v) for v in got] == [bands.classify(v) for v in exact]
    assert watch.calls == 600
    assert watch.pair_queries < 0.5 * 600 * len(watch.pairs)  # it does skip

    # one at a time: the same exact values, bounds as honest (maybe not the same bounds)
    one_by_one = ClearanceWatch(ets7, threshold)
    singles = np.array([one_by_one.clearance_m(q) for q in path])
    np.testing.assert_array_equal(singles[near], got[near])
    assert np.array_equal(singles <= threshold, near)
    assert np.all(singles <= exact + 1e-9)


def test_an_infinite_threshold_is_exact_every_time(ets7: RobotDescription) -> None:
    path = _random_motion(np.random.default_rng(5), 60, np.zeros(6))
    watch = ClearanceWatch(ets7, math.inf)
    got = watch.clearances_m(path)
    np.testing.assert_allclose(got, [watch.exact_m(q) for q in path], atol=1e-12)


def test_the_watch_refuses_what_it_cannot_watch(ets7: RobotDescription) -> None:
    watch = ClearanceWatch(ets7, 0.08)
    with pytest.raises(InvalidInput, match="7 values; the robot has 6 joints"):
        watch.clearance_m(np.zeros(7))
    assert math.isnan(watch.clearance_m(np.full(6, np.nan)))
    with pytest.raises(InvalidInput, match="threshold"):
        ClearanceWatch(ets7, math.nan)
    with pytest.raises(InvalidInput, match="max_age"):
        ClearanceWatch(ets7, 0.08, max_age=0)
    with pytest.raises(InvalidInput, match="no <collision> shapes"):
        ClearanceWatch((ets7.model, None), 0.08)  # type: ignore[arg-type]


def test_max_age_refreshes_every_pair(ets7: RobotDescription) -> None:
    watch = ClearanceWatch(ets7, -1.0, max_age=5)  # a threshold nothing reaches
    still = np.tile(ets7.pose_joints_rad("B"), (13, 1))
    watch.clearances_m(still)
    # the first call, and each after five answered from bounds, ask every pair
    assert watch.pair_queries == 3 * len(watch.pairs)


def test_a_still_arm_asks_coal_once(ets7: RobotDescription) -> None:
    """Held still (sensor noise only), every answer comes from the bounds."""
    watch = ClearanceWatch(ets7, DEFAULT_LIMITS["clearance_m"].least)
    rng = np.random.default_rng(2)
    still = np.zeros(6) + rng.normal(0.0, np.radians(0.005), (200, 6))
    got = np.concatenate([watch.clearances_m(still[i : i + 20]) for i in range(0, 200, 20)])
    assert watch.pair_queries == len(watch.pairs)
    exact = watch.exact_m(still[-1])
    assert np.all(got <= exact + 1e-9) and np.all(got > exact - 0.005)
