"""Small, valid objects to store: a plan, wire commands, telemetry frames; a pass stored
with its plan (and its frames)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from sqlalchemy.orm import Session

from planner.attitude_control import AcsMode
from planner.plan import AcsCommand, Plan, Prediction, Segment
from server.storage import repository as repo
from server.storage.models import PassRecord
from telemetry.layout import DEFAULT_LAYOUT, FrameLayout
from telemetry.wire import (
    AcsCommandMsg,
    AcsModeName,
    JointCommandMsg,
    TelemetryFrame,
)

#: Onboard time of frame 0, and the 10 Hz frame period.
T0_NS = 5_000_000_000_000
FRAME_PERIOD_NS = 100_000_000
#: When the ground received the frames a test stores.
RECEIVED_NS = 1_790_000_000_000_000_000


def still_prediction(duration_s: float, n_joints: int, k: int) -> Prediction:
    """A short prediction: ``k`` samples over ``duration_s`` of an arm of ``n_joints`` at
    zero, the base and the hand still."""
    return Prediction(
        t_s=np.linspace(0.0, duration_s, k),
        joints_rad=np.zeros((k, n_joints)),
        quat_orbit_from_base_xyzw=np.tile([0.0, 0.0, 0.0, 1.0], (k, 1)),
        rpy_base_rad=np.zeros((k, 3)),
        omega_base_orbit_radps=np.zeros((k, 3)),
        hand_pos_orbit_m=np.ones((k, 3)),
        quat_orbit_from_hand_xyzw=np.tile([0.0, 0.0, 0.0, 1.0], (k, 1)),
        reaction_momentum_orbit_nms=np.zeros((k, 3)),
        wheel_momentum_nms=np.zeros((k, 3)),
    )


def make_plan(n_commands: int = 9, experiment: str = "ptp", n_joints: int = 6) -> Plan:
    """A small plan of a robot of ``n_joints`` (ETS-VII: 6): joint commands 0.25 s apart,
    one ACS command, a short prediction."""
    times_s = np.arange(n_commands, dtype=np.float64) * 0.25
    joints_rad = np.linspace(0.0, 0.2, n_commands)[:, None] * np.ones(n_joints)
    prediction = still_prediction(float(times_s[-1]), n_joints, 5)
    return Plan(
        experiment=experiment,
        parameters={"out_speed_mps": 0.01, "label": "A->B"},
        initial_joints_rad=np.zeros(n_joints),
        command_times_s=times_s,
        command_joints_rad=joints_rad,
        segments=(Segment("move", "ptp", 0.0, float(times_s[-1])),),
        prediction=prediction,
        metrics={"max_rate_degps": 1.5},
        acs_commands=(AcsCommand(t_s=0.0, mode=AcsMode.FREE_DRIFT),),
    )


def make_commands(n: int, *, first_seq: int = 0) -> list[JointCommandMsg | AcsCommandMsg]:
    """An ACS command, then joint commands on the 4 Hz grid."""
    out: list[JointCommandMsg | AcsCommandMsg] = [
        AcsCommandMsg(
            seq=first_seq,
            execute_time_ns=T0_NS,
            mode=AcsModeName.FREE_DRIFT,
            target_quat_orbit_from_base_xyzw=[0.0, 0.0, 0.1, 0.995],
            feedforward=True,
        )
    ]
    for i in range(1, n):
        out.append(
            JointCommandMsg(
                seq=first_seq + i,
                execute_time_ns=T0_NS + i * 250_000_000,
                joints_rad=[0.01 * i, -0.01 * i, 0.0, 0.5, 0.0, 0.25],
            )
        )
    return out


def make_frame(
    seq: int, rng: np.random.Generator | None = None, layout: FrameLayout = DEFAULT_LAYOUT
) -> TelemetryFrame:
    """Frame ``seq`` at 10 Hz of a robot of ``layout`` (ETS-VII's by default); random values
    when ``rng`` is given, else values from seq."""
    rng = rng if rng is not None else np.random.default_rng(seq)
    v = rng.normal(size=len(layout.float_fields)).tolist()
    # a unit attitude quaternion, as every real frame has (the link refuses others)
    fields = layout.float_fields
    quat = [fields.index(name) for name in ("qx", "qy", "qz", "qw")]
    norm = sum(v[k] ** 2 for k in quat) ** 0.5
    for k in quat:
        v[k] /= norm
    row = (
        seq,
        T0_NS + seq * FRAME_PERIOD_NS,
        *v,
        "feedback" if seq % 2 else "free_drift",
        bool(seq % 3),
        seq % 7,
        None if seq % 5 == 0 else T0_NS + seq * 1000,
        seq // 4 - 1,
        0,  # reception time: not part of the wire frame
    )
    return layout.frame(row)


def make_frames(
    seqs: range | list[int], seed: int = 0, layout: FrameLayout = DEFAULT_LAYOUT
) -> list[TelemetryFrame]:
    rng = np.random.default_rng(seed)
    return [make_frame(s, rng, layout) for s in seqs]


def store_pass(
    session: Session,
    plan: Plan | None = None,
    *,
    name: str = "p",
    los_time_ns: int = 10**12,
    relay: str = "TDRS",
    frames: Sequence[TelemetryFrame] = (),
    reception_time_ns: int = RECEIVED_NS,
) -> PassRecord:
    """A pass of ``plan`` (``make_plan()`` by default), stored with it at time 0, from AOS 0
    to ``los_time_ns``, and its ``frames`` ingested (received at ``reception_time_ns``); not
    committed."""
    plan_id = repo.add_plan(
        session=session, plan=plan if plan is not None else make_plan(), created_at_ns=0
    ).id
    record = repo.add_pass(
        session=session,
        name=name,
        plan_id=plan_id,
        aos_time_ns=0,
        los_time_ns=los_time_ns,
        relay=relay,
        created_at_ns=0,
    )
    if frames:
        repo.ingest_frames(
            session=session,
            pass_id=record.id,
            frames=frames,
            reception_time_ns=reception_time_ns,
        )
    return record
