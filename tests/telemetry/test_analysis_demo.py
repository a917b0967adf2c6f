"""The post-pass analyses on the demo pass (tests/telemetry/conftest.py: the whole schedule
flown through the simulated vehicle with sensor noise and gravity gradient).

Numbers measured on the demo pass (seed 7) are quoted next to each tolerance.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from planner.dynamics import DynamicsWorkspace
from planner.frames import matrix_from_quat_xyzw
from planner.state import State
from telemetry.analysis import PassAnalysis, analyse_pass, arm_reaction
from telemetry.analysis._common import window_mask
from telemetry.recording import PassRecording


@pytest.fixture(scope="module")
def analysis(demo_recording: PassRecording, model: object) -> PassAnalysis:
    return analyse_pass(demo_recording)


def test_every_experiment_is_analysed(analysis: PassAnalysis) -> None:
    assert analysis.experiments == ("ptp", "reactionless", "gjm", "coordination", "nonholonomic")
    assert analysis.skipped == ()
    assert analysis.missing == ()
    assert not analysis.coverage.ends_early and analysis.coverage.gaps_s == ()


def test_to_dict_is_json_and_deterministic(
    analysis: PassAnalysis, demo_recording: PassRecording
) -> None:
    doc = analysis.to_dict()
    text = json.dumps(doc, allow_nan=False)
    assert json.loads(text) == doc
    assert analyse_pass(demo_recording).to_dict() == doc


# --- experiment 1 (Fig. 5) ---------------------------------------------------------------


def test_ptp_settles_far_longer_than_the_reactionless_legs(analysis: PassAnalysis) -> None:
    reaction = analysis.reaction
    assert reaction is not None and reaction.settle_band_deg == 0.05
    (ptp,) = reaction.motion("ptp")
    legs = reaction.motion("reactionless")
    assert [m.segment for m in legs] == ["reactionless: B->C", "reactionless: C->B"]
    # Measured: PTP 90.1 s to within 0.05 deg of its final attitude (flight: about 100 s),
    # peak 0.93 deg; the reactionless legs never leave the band (0 s), peaks 0.084 and
    # 0.023 deg (mostly the PTP's recovery tail).
    assert ptp.settling_time_s is not None and ptp.settling_time_s > 50.0
    assert ptp.peak_excursion_deg is not None and ptp.peak_excursion_deg > 0.4
    for leg in legs:
        assert leg.settling_time_s is not None and leg.settling_time_s < 5.0, leg
        assert leg.peak_excursion_deg is not None and leg.peak_excursion_deg < 0.1 * (
            ptp.peak_excursion_deg
        )


def test_faster_reactionless_leg_has_the_larger_residual_reaction(
    analysis: PassAnalysis,
) -> None:
    assert analysis.reaction is not None
    fast, slow = analysis.reaction.motion("reactionless")
    # Speeds from the measured joints (plan: 0.015 and 0.0075 m/s; measured 0.0158 and
    # 0.0081).
    assert fast.peak_hand_speed_mps is not None and slow.peak_hand_speed_mps is not None
    assert fast.peak_hand_speed_mps == pytest.approx(0.015, rel=0.15)
    assert slow.peak_hand_speed_mps == pytest.approx(0.0075, rel=0.15)
    # RMS |H~_bm phi'| over the leg: 0.060 against 0.0187 N m s (noise-free truth 0.061
    # against 0.018; noise floor in the hold after, 0.005 N m s). With one lag for every
    # joint it was 0.0095 against 0.0056: the joints' different lags are the reaction.
    assert fast.rms_reaction_momentum_nms is not None and slow.rms_reaction_momentum_nms
    assert fast.rms_reaction_momentum_nms > 1.4 * slow.rms_reaction_momentum_nms
    # The raw attitude excursion also orders them (0.048 against 0.030 deg), but that is
    # mostly the PTP's recovery tail (see test_analysis_ideal), not the legs' reaction.
    assert fast.peak_excursion_deg is not None and slow.peak_excursion_deg is not None
    assert fast.peak_excursion_deg > slow.peak_excursion_deg


def test_faster_reactionless_leg_leaves_the_larger_attitude_residual(
    analysis: PassAnalysis,
) -> None:
    """Flight (Fig. 5 bottom): the reactionless legs turned the base a little, more at the
    faster hand speed. A strict xfail while every joint lagged 0.3 s: a common lag only
    re-times a null-space path (residual 7.8e-4 against 3.2e-4 deg noise-free, under the
    0.005 deg attitude noise). ETS-VII's servos now lag by joint (planner.simulation
    .ETS7_SERVO_LAG_S), and the residual is what the attitude does within 5 s against the
    plan (telemetry.analysis.reaction): the servo lag's reaction steps in and out with the
    hand speed in about a second, while the wheels' correction of it, the same for both
    speeds, builds over tens of seconds. Taken instead from the attitude before each leg, as
    before, the slow leg carries the wheels' correction of both legs and the order goes with
    the noise: 0.0052 against 0.0045 deg noise-free, 0.0067 against 0.0079 with it."""
    assert analysis.reaction is not None
    fast, slow = analysis.reaction.motion("reactionless")
    assert fast.peak_residual_deg is not None and slow.peak_residual_deg is not None
    # Measured 0.0102 against 0.0081 deg (noise-free 0.0074 against 0.0040; with one common
    # lag, noise alone gives 0.0048 to 0.0067 over seeds 1, 2, 3 and 7).
    assert fast.peak_residual_deg > slow.peak_residual_deg
    assert fast.peak_residual_deg > 0.008


def test_reaction_momentum_obeys_momentum_conservation_in_free_drift(
    demo_recording: PassRecording, workspace: DynamicsWorkspace
) -> None:
    """GJM approach, free drift: ``H~_bm phi' + H~_b w_b + R h_w`` stays constant (eq. 3)
    while ``H~_bm phi'`` alone reaches about 4 N m s."""
    seg = demo_recording.plan.segment("gjm: approach")
    t = demo_recording.t_s()
    rows = window_mask(t, seg.t_start_s - 5.0, seg.t_end_s + 5.0)
    f = demo_recording.frames
    result = arm_reaction(
        workspace,
        t[rows],
        f.joints_rad[rows],
        f.quat_orbit_from_base_xyzw[rows],
        f.omega_base_in_base_radps[rows],
    )
    wheels = np.array(
        [
            matrix_from_quat_xyzw(q) @ h
            for q, h in zip(
                f.quat_orbit_from_base_xyzw[rows], f.wheel_momentum_nms[rows], strict=True
            )
        ]
    )
    arm = result.reaction_momentum_orbit_nms
    total = arm + result.base_momentum_orbit_nms + wheels
    swing = float(np.max(np.linalg.norm(arm, axis=1)))  # the arm starts and ends at rest
    drift = float(np.max(np.linalg.norm(total - total.mean(axis=0), axis=1)))
    assert swing > 3.0  # measured 4.1 N m s
    # Measured 0.25 N m s: the gyro's 9e-6 rad/s noise times H~_b (up to 7090 kg m^2) is
    # 0.06 N m s 1-sigma per axis; gravity gradient adds under 0.01 N m s in 30 s.
    assert drift < 0.1 * swing, (drift, swing)


# --- Fig. 6 ---------------------------------------------------------------------------------


def test_joint_tracking_shows_servo_lag(
    analysis: PassAnalysis, demo_recording: PassRecording
) -> None:
    tracking = analysis.joint_tracking
    assert tracking is not None
    legs = [s for s in tracking.segments if s.kind == "reactionless"]
    assert len(legs) == 2
    # The faster leg lags more on every moving joint: error ~ rate x servo lag.
    fast, slow = legs
    assert max(fast.rms_error_deg) > 1.7 * max(slow.rms_error_deg)  # 0.86 against 0.43 deg
    # Measured: joint 4 lags most, as in the flight (RMS 0.86 deg on the fast leg; joint 3,
    # which moves a little faster, 0.60 deg with its shorter lag, 0.35 s against 0.55 s).
    assert fast.worst_joint == 4 and slow.worst_joint == 4
    assert fast.rms_error_deg[3] > 1.2 * fast.rms_error_deg[2]
    # A lag, not noise: the error has the opposite sign of the commanded rate.
    rows = tracking.segment_index == tracking.segments.index(fast)
    j = fast.worst_joint - 1
    rate = np.gradient(tracking.commanded_deg[rows, j], tracking.t_s[rows])
    error = tracking.error_deg[rows, j]
    assert float(np.corrcoef(rate, error)[0, 1]) < -0.8


# --- experiment 2 (Fig. 8) --------------------------------------------------------------


def test_hand_attitude_is_held_while_the_base_turns(analysis: PassAnalysis) -> None:
    hand = analysis.hand_attitude
    assert hand is not None
    for span in ("approach", "retreat"):
        hold = hand.hold(span)
        assert hold.base_change_max_deg is not None and hold.hand_change_max_deg is not None
        # Measured: base 0.59 / 0.66 deg, hand 0.073 / 0.051 deg (flight: +-0.1 deg; 0.092 /
        # 0.087 when the GJM began 45 s after its transfer, the base still recovering; the
        # pitch joints' different lags turn the hand, planner.simulation.ETS7_SERVO_LAG_S).
        assert hold.base_change_max_deg > 0.45, hold
        assert hold.hand_change_max_deg < 0.15, hold
        assert hold.hold_ratio is not None and hold.hold_ratio < 0.25
    # The pointing plot starts at the planned -23 deg hand pitch.
    assert hand.pointing_pitch_deg[0] == pytest.approx(-23.0, abs=0.3)


def test_hand_attitude_frames_compose(
    analysis: PassAnalysis, demo_recording: PassRecording, workspace: DynamicsWorkspace
) -> None:
    """rot_orbit_from_hand = rot_orbit_from_base @ rot_base_from_hand, and the pointing
    angles are the approach axis's yaw and pitch in the orbit frame."""
    hand = analysis.hand_attitude
    assert hand is not None
    t = demo_recording.t_s()
    k = int(np.flatnonzero(np.isclose(t, hand.t_s[300]))[0])
    f = demo_recording.frames
    rot_base_from_hand = workspace.hand_pose(State(joints_rad=f.joints_rad[k])).rot_base_from_hand
    rot = matrix_from_quat_xyzw(f.quat_orbit_from_base_xyzw[k]) @ rot_base_from_hand
    axis = rot[:, 0]
    assert np.degrees(np.arctan2(axis[1], axis[0])) == pytest.approx(
        hand.pointing_yaw_deg[300], abs=1e-9
    )
    assert np.degrees(np.arcsin(-axis[2])) == pytest.approx(hand.pointing_pitch_deg[300], abs=1e-9)


# --- experiment 3 (Fig. 9) --------------------------------------------------------------


def test_phase_plane_variants(analysis: PassAnalysis) -> None:
    plane = analysis.phase_plane
    assert plane is not None
    assert [v.variant for v in plane.variants] == ["feedback", "feedforward", "offset"]
    fb, ff, off = plane.variants
    # Each variant starts at the phase plane's origin, as in flight (paper 3.5): measured
    # -0.028, -0.037, -0.034 deg (at rest inside the law's 0.035 deg dead band, where gravity
    # gradient leaves it, after the 120 s wait; 80 s left (c) about -0.2 deg down).
    for v in plane.variants:
        assert v.start_pitch_deg is not None and abs(v.start_pitch_deg) < 0.05, v.variant
    # Measured pitch ranges (calibrated law): feedback -0.36..+0.50, feedforward -0.32..+0.70
    # (the recovery adds to the reversal's reaction: strongest positive overshoot, as in
    # flight), offset -0.53..+0.03 deg.
    assert ff.pitch_max_deg is not None and fb.pitch_max_deg is not None
    assert off.pitch_max_deg is not None
    assert ff.pitch_max_deg > max(fb.pitch_max_deg, off.pitch_max_deg) + 0.05
    # Feedforward's first response is faster than feedback's, within -0.3 deg (flight):
    # measured first dip -0.26 deg against feedback's -0.36.
    assert ff.first_dip_deg is not None and fb.first_dip_deg is not None
    assert -0.3 < ff.first_dip_deg < 0.0
    assert ff.first_dip_deg > fb.first_dip_deg + 0.05
    # Every variant is back within 0.05 deg of the phase plane's origin (the target the loop
    # holds) before its 120 s wait ends, the last 5 s inside: feedback 111.9 s, feedforward
    # 114.7 s, offset 99.8 s (test_offset_destination_settles_fastest orders them).
    for v in plane.variants:
        assert v.settling_time_s is not None and v.settling_time_s < 120.0 - 5.0, v.variant


def test_offset_destination_has_the_smallest_range(analysis: PassAnalysis) -> None:
    """Flight: range (c) < (a) < (b). Holds with the offset held over the whole back-and-forth
    motion (the paper's one switch on after the start and one off after the stop): the base
    waits tilted for the reversal's reaction, which brings it back, so (c) barely overshoots.
    Offsetting each leg by its own Omega_b (+0.35 deg on the way back) raised the peak and
    gave (a) 0.91 < (c) 0.97 < (b) 1.11 deg; it was a strict xfail until issue #13."""
    plane = analysis.phase_plane
    assert plane is not None
    fb, ff, off = (plane.variant(v) for v in ("feedback", "feedforward", "offset"))
    assert off.pitch_range_deg is not None and fb.pitch_range_deg is not None
    assert ff.pitch_range_deg is not None
    # Measured: offset 0.56 (-0.53..+0.03), feedback 0.86, feedforward 1.02 deg.
    assert off.pitch_range_deg + 0.1 < fb.pitch_range_deg < ff.pitch_range_deg


def test_offset_destination_settles_fastest(analysis: PassAnalysis) -> None:
    """Flight: (c) settles fastest after the arm stops. A strict xfail until the law was
    calibrated on the demo pass itself (docs/spacecraft.md): with wn 0.023 rad/s, zeta 0.85
    and an 18 s rate filter, (c) came back from its offset with the loop still pulling the
    other way and undershot to -0.32 deg, (a) 98.2 < (b) 114.5 s and (c) not settled by the
    end of its 120 s wait. With the calibrated law (wn 0.030 rad/s, zeta 0.55, an 11 s
    filter, a 0.035 deg dead band) (c) approaches the origin from below and never
    overshoots it (its maximum +0.03 deg), while (a) and (b) swing to +0.50 and +0.70 deg
    after the stop and cross the origin before they settle."""
    plane = analysis.phase_plane
    assert plane is not None
    fb, ff, off = (plane.variant(v) for v in ("feedback", "feedforward", "offset"))
    assert off.settling_time_s is not None and fb.settling_time_s is not None
    assert ff.settling_time_s is not None
    # Measured: (c) 99.8 < (a) 111.9 < (b) 114.7 s (seeds 1, 2, 3 and 5: (c) first by 10 s
    # or more).
    assert off.settling_time_s < min(fb.settling_time_s, ff.settling_time_s)


def test_gyro_pitch_rate_integrates_to_the_pitch(analysis: PassAnalysis) -> None:
    """Frames check: the gyro's base-frame y rate, integrated, against the pitch change of the
    quaternions (both as the phase plane shows them)."""
    plane = analysis.phase_plane
    assert plane is not None
    v = plane.variant("feedback")
    dt = np.diff(v.t_s)
    integral = np.concatenate(
        [[0.0], np.cumsum(0.5 * (v.pitch_rate_degps[1:] + v.pitch_rate_degps[:-1]) * dt)]
    )
    change = v.pitch_deg - v.pitch_deg[0]
    assert v.pitch_range_deg is not None and v.pitch_range_deg > 0.4  # measured 0.86 deg
    # Measured within 0.006 deg: 0.005 deg attitude noise averaged over 1 s plus the gyro's
    # random walk (9e-6 rad/s over 160 s at 10 Hz: 0.002 deg); a sign or axis slip would
    # give errors of the order of the range.
    assert float(np.max(np.abs(integral - change))) < 0.03 * v.pitch_range_deg


# --- experiment 4 (Fig. 11) -------------------------------------------------------------


def test_nonholonomic_end_point_errors(analysis: PassAnalysis) -> None:
    end = analysis.endpoint
    assert end is not None
    assert end.target_joints_deg == pytest.approx((0.0,) * 6, abs=1e-9)
    # Measured: joints within 0.0020 deg of phi_end (encoder noise 0.005 deg, averaged).
    assert end.max_joint_error_deg is not None and end.max_joint_error_deg < 0.01
    # Measured change error (-0.017, +0.073, +0.001) deg: gravity gradient in 125 s of free
    # drift, which the pass prediction leaves out (flight: 0.2 deg of roll).
    assert end.attitude_change_error_deg is not None
    assert float(np.linalg.norm(end.attitude_change_error_deg)) < 0.2
    assert end.attitude_error_angle_deg is not None and end.attitude_error_angle_deg < 0.2


# --- predicted against flown ------------------------------------------------------------


def test_predicted_vs_flown_per_segment(analysis: PassAnalysis) -> None:
    comparison = analysis.predicted_vs_flown
    assert comparison is not None
    assert len(comparison.segments) == 30  # experiment 3 has no pause between its legs
    for seg in comparison.segments:
        assert seg.attitude_peak_deg is not None and seg.joint_peak_max_deg is not None
        # Measured at most 0.119 deg (nonholonomic tail, gravity gradient in free drift).
        assert seg.attitude_peak_deg < 0.15, seg
        if seg.kind in ("hold", "settle") and seg.segment != "reactionless: pause at C":
            assert seg.joint_peak_max_deg < 0.05, seg  # servos caught up (measured 0.035)
    # The pause at C starts as the fast leg stops: its peak is the wrist still catching up
    # in the first second (joint 4, 0.55 s lag; measured 0.16 deg, 0.037 with one 0.3 s lag).
    pause = comparison.segment("reactionless: pause at C")
    assert pause.joint_peak_max_deg is not None and pause.joint_peak_max_deg < 0.3
    ptp = comparison.segment("ptp: A->B")
    assert ptp.joint_peak_max_deg is not None and ptp.joint_peak_max_deg > 0.3  # lag, 1.49


# --- flight against ours (telemetry.analysis.paper) --------------------------------------


def test_flight_against_ours_on_the_demo_pass(analysis: PassAnalysis) -> None:
    """The verdicts on today's demo pass, from its numbers (the identification and resim
    rows need their own analyses and are "not measured" here)."""
    from server.services.analyses import numbers_only
    from telemetry.analysis import Sources, compare_with_flight

    rows = {c.id: c for c in compare_with_flight(Sources(numbers_only(analysis.to_dict())))}
    verdicts = {k: c.verdict for k, c in rows.items()}
    # Measured: PTP 90.1 s, peak 0.93 deg; legs 0.084 / 0.023 deg against 0.93; RMS 0.060
    # against 0.0187 N m s; GJM base pitch -0.580 deg, hand 0.073 deg; variants start at
    # -0.028, -0.037, -0.034 deg; (a) -0.36..+0.50 deg; (b) dip -0.26, peak +0.70 deg; (c)
    # range 0.56 < (a) 0.86 < (b) 1.02 deg; settling (c) 99.8 < (a) 111.9 < (b) 114.7 s;
    # endpoint 0.107 deg. Every row of the paper this pass measures.
    for row in (
        "ptp_settling",
        "reactionless_little_disturbance",
        "reactionless_grows_with_speed",
        "gjm_base_pitch",
        "gjm_hand_hold",
        "coordination_start",
        "coordination_feedback_range",
        "coordination_feedforward",
        "coordination_offset_range",
        "coordination_offset_settling",
        "nonholonomic_endpoint",
    ):
        assert verdicts[row] == "reproduced", rows[row]
    # Experiment 3's orderings against the flight's: the range (c) < (a) < (b), (c) settling
    # fastest and (b) overshooting most, as in flight.
    from telemetry.analysis.paper import phase_plane_ordering

    ordering = phase_plane_ordering(analysis.to_dict()["phase_plane"])
    assert [r.holds for r in ordering] == [True, True, True], ordering
    assert (
        verdicts["gravity_gradient_drift"] == verdicts["inertia_identification"] == ("not measured")
    )
    plane = analysis.phase_plane
    assert plane is not None
    ff = plane.variant("feedforward")
    assert ff.first_dip_deg is not None and ff.first_dip_t_s is not None
    assert ff.t_start_s <= ff.first_dip_t_s <= (ff.forward_end_s or 0.0)
    assert ff.peak_deg == ff.pitch_max_deg
