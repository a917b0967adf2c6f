"""The spacecraft process against a minimal ground over a real websocket, accelerated 20x.

In-process (the same code the CLI runs) except for the last test, which starts the real
``hikoboshi spacecraft`` process and stops it with SIGTERM.
"""

from __future__ import annotations

import asyncio
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from spacecraft.faults import parse_fault
from spacecraft.link import Outage
from spacecraft.process import SpacecraftProcess
from spacecraft.vehicle_config import VehicleConfig
from telemetry.limits import attitude_error_deg
from telemetry.wire import (
    DEFAULT_SCHEDULE_CAPACITY,
    CommandStage,
    JointCommandMsg,
    RejectReason,
    SafeExit,
    Safing,
    ScheduleDelete,
)
from tests.spacecraft.ground_stub import SCALE, TOKEN, GroundStub, run_session

pytestmark = pytest.mark.realtime  # flies a vehicle or serves a live link in wall time

PERIOD_NS = 250_000_000


def _next_tag(stub: GroundStub, lead_s: float) -> int:
    t = stub.onboard_now_ns() + round(lead_s * 1e9)
    return math.ceil(t / PERIOD_NS) * PERIOD_NS


def test_commands_execute_exactly_at_their_tags_late_and_duplicates_refused() -> None:
    joints = [np.radians([0.1 * k, -0.05 * k, 0.0, 0.05 * k, 0.0, 0.0]) for k in range(8)]
    tags: list[int] = []

    async def scenario(stub: GroundStub, process: SpacecraftProcess) -> None:
        tag0 = _next_tag(stub, 6.0)  # one-way delay 3 s + 2 s margin + slack
        for k, q in enumerate(joints):
            tags.append(tag0 + k * PERIOD_NS)
            await stub.send(JointCommandMsg(seq=k, execute_time_ns=tags[-1], joints_rad=list(q)))
        late = _next_tag(stub, -2.0)
        await stub.send(JointCommandMsg(seq=100, execute_time_ns=late, joints_rad=[0.3] * 6))
        await stub.send(JointCommandMsg(seq=3, execute_time_ns=tags[3], joints_rad=[0.2] * 6))

        def done() -> bool:
            executed = {a.seq for a in stub.acks if a.stage is CommandStage.EXECUTED}
            last = max((f.generation_time_ns for f in stub.frames.values()), default=0)
            return executed >= set(range(8)) and last > tags[-1] + 3 * 10**9

        await stub.wait_for(done, timeout_s=20.0)

    stub, _ = run_session(scenario)
    executed = {a.seq: a for a in stub.acks if a.stage is CommandStage.EXECUTED}
    assert [executed[k].onboard_time_ns for k in range(8)] == tags  # exactly at the tags
    rejected = {a.seq: a for a in stub.acks if a.stage is CommandStage.REJECTED}
    assert rejected[100].reason is RejectReason.LATE and 100 not in executed
    assert rejected[3].reason is RejectReason.DUPLICATE
    frames = sorted(stub.frames.values(), key=lambda f: f.seq)
    by_time = {f.generation_time_ns: f for f in frames}
    coinciding = [k for k, tag in enumerate(tags) if tag in by_time]  # every 0.5 s
    assert len(coinciding) >= 3
    for k in coinciding:
        np.testing.assert_allclose(by_time[tags[k]].joint_targets_rad, joints[k], atol=1e-12)
    # the duplicate (0.2 rad on every joint) never took effect
    assert all(max(f.joint_targets_rad) < 0.1 for f in frames)
    # commands stopped: the arm holds the last target
    after = [f for f in frames if f.generation_time_ns > tags[-1]]
    assert len(after) >= 20
    for f in after:
        np.testing.assert_allclose(f.joint_targets_rad, joints[-1], atol=1e-12)
    settled = [f for f in after if f.generation_time_ns > tags[-1] + 2 * 10**9]
    spread = np.ptp(np.array([f.joints_rad for f in settled]), axis=0)
    assert np.max(spread) < np.radians(0.05)  # still, up to encoder noise and servo settling


def test_every_frame_reaches_the_ground_exactly_once_through_loss_and_an_outage() -> None:
    async def scenario(stub: GroundStub, process: SpacecraftProcess) -> None:
        # 90 s onboard: a 30 s LOS from 20 s to 50 s, 10 % loss both ways all along.
        await asyncio.sleep(90.0 / SCALE)

    stub, process = run_session(scenario, loss=0.1, outages=(Outage(20.0, 50.0),))
    produced = process.vehicle.next_telemetry_seq
    assert produced >= 800  # 10 Hz over 90 s
    assert sorted(stub.frames) == list(range(produced))  # every frame, stored once
    assert process.store.unacked == 0
    # the scenario was real: frames were lost and sent again, and some arrived twice
    assert process.store.resent > 300  # at least the 30 s outage's worth
    assert process.downlink_link.stats.dropped_outage > 0
    assert process.downlink_link.stats.dropped_loss > 0
    assert stub.duplicates >= 0


def test_hostile_messages_get_error_replies_and_the_vehicle_carries_on() -> None:
    async def scenario(stub: GroundStub, process: SpacecraftProcess) -> None:
        for text in (
            "{not json",
            '{"v":2,"type":"self_destruct"}',
            '{"v":2,"type":"ping","ping_id":"abc","ground_time_ns":0}',
            '{"v":9,"type":"ping"}',
            '{"v":2,"type":"ping","pad":"' + "x" * 300_000 + '"}',
            b"\xff\xfe\x00binary",
            # version 1 is not served, commands included: an error, not a command_ack
            '{"v":1,"type":"ping","ping_id":1,"ground_time_ns":0}',
            '{"v":1,"type":"command","kind":"joints","seq":56,"execute_time_ns":0,'
            '"joints_rad":[0,0,0,0,0,0]}',
            # the ground's own error reply is read, never answered (no ping-pong of errors)
            '{"v":2,"type":"error","reason":"the spacecraft said something odd"}',
        ):
            await stub.send(text)
        bad_command = (
            '{"v":2,"type":"command","kind":"joints","seq":55,"execute_time_ns":0,'
            '"joints_rad":[0,0,0,0,0,"oops"]}'
        )
        await stub.send(bad_command)
        await stub.wait_for(
            lambda: len(stub.errors) >= 8 and any(a.seq == 55 for a in stub.acks), 10.0
        )
        seq_before = max(stub.frames)
        # Past the socket's own limit the connection closes; the spacecraft reconnects.
        await stub.send('{"v":2,"type":"ping","pad":"' + "x" * (5 * 2**20) + '"}')
        await stub.wait_for(lambda: len(stub.hellos) >= 2, 10.0)
        await stub.wait_for(lambda: max(stub.frames) > seq_before + 30, 10.0)

    stub, process = run_session(scenario)
    reasons = " | ".join(e.reason for e in stub.errors)
    for expected in ("not JSON", "unknown message type", "ping_id", "version 9", "exceeds"):
        assert expected in reasons
    v1 = [e for e in stub.errors if "protocol version 1 is not served" in e.reason]
    assert [e.ref_type for e in v1] == ["ping", "command"]
    assert "this end speaks 2" in v1[0].reason
    assert not any(a.seq == 56 for a in stub.acks)
    assert not any(e.ref_type == "error" for e in stub.errors)
    malformed = next(a for a in stub.acks if a.seq == 55)
    assert malformed.stage is CommandStage.REJECTED and malformed.reason is RejectReason.MALFORMED
    assert process.connections == 2
    assert sorted(stub.frames) == list(range(process.vehicle.next_telemetry_seq))


def test_a_dropped_link_changes_nothing_the_schedule_executes_and_copies_get_their_acks() -> None:
    """The websocket dropping is no LOS hold (the default policy is ``continue``): the loaded
    commands execute at their tags, and copies sent after reconnecting are answered with the
    stored acknowledgements."""
    joints = [np.radians([0.5 * k, 0, 0, 0, 0, 0]) for k in range(4)]  # 2 deg/s
    tags: list[int] = []

    async def scenario(stub: GroundStub, process: SpacecraftProcess) -> None:
        hello = stub.hellos[0]
        assert hello.schedule_capacity == DEFAULT_SCHEDULE_CAPACITY
        assert (hello.los_policy, hello.los_hold_after_s) == ("continue", None)
        tag0 = _next_tag(stub, 25.0)  # acks back, a reconnection and a copy before the tags
        cmds = []
        for k, q in enumerate(joints):
            tags.append(tag0 + k * PERIOD_NS)
            cmds.append(JointCommandMsg(seq=k, execute_time_ns=tags[-1], joints_rad=list(q)))
            await stub.send(cmds[-1])
        await stub.wait_for(lambda: len(stub.acks) >= 4, 10.0)
        assert all(a.stage is CommandStage.RECEIVED for a in stub.acks)
        assert stub.connection is not None
        await stub.connection.close()
        await stub.wait_for(lambda: len(stub.hellos) >= 2, 10.0)
        assert stub.hellos[1].last_command_seq == 3
        await stub.send(cmds[3])  # a retransmission: "you already have it"
        await stub.wait_for(lambda: len(stub.acks) >= 5, 10.0)
        await stub.wait_for(
            lambda: sum(a.stage is CommandStage.EXECUTED for a in stub.acks) >= 4, 20.0
        )
        await stub.send(cmds[0])
        await stub.wait_for(lambda: len(stub.acks) >= 10, 10.0)

    stub, _ = run_session(scenario)
    assert not any(a.reason is RejectReason.LINK_LOST for a in stub.acks)
    assert not any(a.reason is RejectReason.DUPLICATE for a in stub.acks)
    executed = {a.seq: a for a in stub.acks if a.stage is CommandStage.EXECUTED}
    assert [executed[k].onboard_time_ns for k in range(4)] == tags
    # the copy of seq 3 got "received" (before its tag), the copy of seq 0 "executed"
    received_3 = [a for a in stub.acks if a.seq == 3 and a.stage is CommandStage.RECEIVED]
    assert len(received_3) == 2 and received_3[0] == received_3[1]
    assert [a for a in stub.acks if a.seq == 0][-1] == executed[0]
    assert len([a for a in stub.acks if a.stage is CommandStage.EXECUTED]) == 5
    late = [f for f in stub.frames.values() if f.generation_time_ns >= tags[-1]]
    assert late and all(
        np.allclose(f.joint_targets_rad, joints[-1], rtol=0, atol=1e-12) for f in late
    )


def test_schedule_delete_goes_through_the_relay_and_is_verified() -> None:
    async def scenario(stub: GroundStub, process: SpacecraftProcess) -> None:
        tag0 = _next_tag(stub, 15.0)  # the delete (3 s up) well before the 5th tag
        for k in range(8):
            q = np.radians([0.5 * k, 0, 0, 0, 0, 0])
            await stub.send(
                JointCommandMsg(seq=k, execute_time_ns=tag0 + k * PERIOD_NS, joints_rad=list(q))
            )
        request = ScheduleDelete(request_id=1, from_time_ns=tag0 + 4 * PERIOD_NS, max_seq=7)
        await stub.send(request)
        await stub.send(request)  # a copy: the same report, nothing else
        await stub.wait_for(lambda: len(stub.verifications) >= 2, 10.0)
        await stub.wait_for(
            lambda: sum(a.stage is CommandStage.EXECUTED for a in stub.acks) >= 4, 20.0
        )
        await asyncio.sleep(3.0 / SCALE)  # past the deleted tags

    stub, process = run_session(scenario)
    first, again = stub.verifications
    assert first == again
    assert first.stage == "completed" and first.deleted == 4
    assert first.deleted_ranges == [(4, 7)] and first.executed_after_from == 0
    executed = sorted(a.seq for a in stub.acks if a.stage is CommandStage.EXECUTED)
    assert executed == [0, 1, 2, 3]
    cancelled = process.vehicle.outcome(6)
    assert cancelled is not None and cancelled.reason is RejectReason.CANCELLED
    np.testing.assert_allclose(
        process.vehicle.joint_target_rad(), np.radians([1.5, 0, 0, 0, 0, 0]), rtol=0, atol=1e-12
    )


@pytest.mark.slow
def test_the_real_process_stops_cleanly_on_sigterm_with_nothing_lost() -> None:
    async def main() -> tuple[GroundStub, str, int]:
        stub = GroundStub()
        await stub.start()
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        proc = await asyncio.create_subprocess_exec(
            sys.executable,
            "-m",
            "hikoboshi",
            "spacecraft",
            "--ground",
            stub.url,
            "--token",
            TOKEN,
            "--time-scale",
            str(SCALE),
            "--loss",
            "0.05",
            "--log-format",
            "json",
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            env=env,
        )
        await stub.wait_for(lambda: len(stub.frames) > 100, timeout_s=30.0)
        proc.send_signal(signal.SIGTERM)
        started = time.monotonic()
        _, err = await asyncio.wait_for(proc.communicate(), timeout=40.0)
        assert time.monotonic() - started < 30.0
        await stub.stop()
        return stub, err.decode(), proc.returncode or 0

    stub, stderr, code = asyncio.run(main())
    assert code == 0, stderr
    # every line of its log is JSON, the last the stop's record (a plain line broke it)
    records = [json.loads(line) for line in stderr.splitlines()]
    stopped = [r for r in records if r.get("event") == "spacecraft_stopped"]
    assert len(stopped) == 1 and stopped[0]["frames_unacknowledged"] == 0, records[-3:]
    assert stopped[0]["message"].startswith("spacecraft stopped: 0 frames unacknowledged")
    assert sorted(stub.frames) == list(range(max(stub.frames) + 1))


def test_safing_goes_down_the_relay_and_safe_exit_brings_the_vehicle_back(tmp_path: Path) -> None:
    """An attitude-sensor bias at 20 s onboard: the vehicle safes itself, drops its loaded
    commands (acknowledged safing), and its ``safing`` reports reach the ground over the
    relay, again after a reconnection; a command sent then is refused safing, and a
    ``safe_exit`` (sent twice) is answered nominal with its request_id, twice. The truth log
    has the fault and SAFE's entry and exit; the ground never hears of the fault itself."""
    truth = tmp_path / "truth.jsonl"
    tags: list[int] = []
    at_hello: list[int] = []

    def safing(stub: GroundStub) -> list[Safing]:
        return [m for m in stub.other if isinstance(m, Safing)]

    async def scenario(stub: GroundStub, process: SpacecraftProcess) -> None:
        tag0 = _next_tag(stub, 40.0)  # well after the fault: still queued at 20 s
        for k in range(6):
            tags.append(tag0 + k * PERIOD_NS)
            q = np.radians([0.5 * k, 0, 0, 0, 0, 0])
            await stub.send(JointCommandMsg(seq=k, execute_time_ns=tags[-1], joints_rad=list(q)))
        await stub.wait_for(lambda: len(stub.acks) >= 6, 10.0)
        assert all(a.stage is CommandStage.RECEIVED for a in stub.acks)
        assert not safing(stub)  # loaded before the fault
        await stub.wait_for(lambda: len(safing(stub)) >= 3, 20.0)  # entry + two repeats
        assert stub.connection is not None
        reports_before = len(safing(stub))
        await stub.connection.close()
        await stub.wait_for(lambda: len(stub.hellos) >= 2, 10.0)
        at_hello.append(len(safing(stub)))  # the report after hello is 3 s down the relay
        await stub.wait_for(lambda: len(safing(stub)) > reports_before, 10.0)
        late = JointCommandMsg(seq=10, execute_time_ns=_next_tag(stub, 20.0), joints_rad=[0.0] * 6)
        await stub.send(late)
        await stub.send(SafeExit(request_id=1))
        await stub.send(SafeExit(request_id=1))
        await stub.wait_for(
            lambda: (
                sum(s.exit_request_id == 1 for s in safing(stub)) >= 2
                and any(a.seq == 10 for a in stub.acks)
            ),
            10.0,
        )
        await asyncio.sleep(3.0 / SCALE)  # no more reports once nominal

    stub, process = run_session(
        scenario,
        vehicle=VehicleConfig(faults=(parse_fault("attitude-bias@20,deg=5,axis=y"),)),
        truth_log=truth,
    )
    reports = safing(stub)
    safe = [r for r in reports if r.state == "safe"]
    since = safe[0].since_time_ns
    assert since == process.epoch_ns + 20 * 10**9  # the onset tick
    assert safe[0].trigger is not None and safe[0].trigger.quantity == "attitude_error_deg"
    assert safe[0].trigger.channel == "y" and safe[0].cancelled == 6
    assert all(r.since_time_ns == since and r.cancelled == 6 for r in safe)
    # repeated every onboard second from the entry while connected (none kept for later),
    # and sent right after the second hello
    assert [r.onboard_time_ns for r in safe[:3]] == [since, since + 10**9, since + 2 * 10**9]
    after_hello = reports[at_hello[0]]
    assert after_hello.state == "safe"
    # the first on the new connection: at the hello's time (the vehicle's clock stands on
    # its 10 ms grid, the hello's on the wall clock; the report follows the hello's send)
    delta_ns = after_hello.onboard_time_ns - stub.hellos[1].onboard_time_ns
    assert -0.01e9 <= delta_ns < 1e9
    exits = [r for r in reports if r.state == "nominal"]
    assert len(exits) == 2 and exits[0] == exits[1] and exits[0].exit_request_id == 1
    assert reports[-2:] == exits  # nothing after the exit
    acks = {a.seq: a for a in stub.acks if a.stage is CommandStage.REJECTED}
    assert [acks[k].reason for k in range(6)] == [RejectReason.SAFING] * 6
    assert acks[10].reason is RejectReason.SAFING
    assert not [a for a in stub.acks if a.stage is CommandStage.EXECUTED]
    assert not process.vehicle.safe
    records = [json.loads(line) for line in truth.read_text().splitlines()]
    # ... and at its end the link's counts (spacecraft/process.py)
    assert [r["event"] for r in records] == [
        "start",
        "fault",
        "safing_entry",
        "safing_exit",
        "link",
    ]
    assert records[0]["faults"] == ["attitude-bias@20,deg=5,axis=y"]
    assert records[0]["onboard_time_ns"] == process.epoch_ns and records[0]["safing"] is True
    assert records[1]["onboard_time_ns"] == since and records[2]["onboard_time_ns"] == since
    assert records[3]["request_id"] == 1
    # the fault itself never went down: only what the telemetry shows
    sent = [type(m).__name__ for m in stub.other]
    assert set(sent) == {"Safing"}


@pytest.mark.slow
@pytest.mark.parametrize("safing", [True, False])
def test_the_real_process_takes_faults_and_writes_the_truth_log(
    tmp_path: Path, safing: bool
) -> None:
    """``hikoboshi spacecraft --fault ... --truth-log ...`` (and ``--no-safing``): the bias
    at 2 s safes the vehicle, whose report reaches the ground, or, without safing, only the
    telemetry shows it; either way the truth log has the fault."""
    truth = tmp_path / "truth.jsonl"

    async def main() -> GroundStub:
        stub = GroundStub()
        await stub.start()
        args = ["--fault", "attitude-bias@2,deg=5", "--truth-log", str(truth)]
        if not safing:
            args.append("--no-safing")
        proc = await asyncio.create_subprocess_exec(
            *[sys.executable, "-m", "hikoboshi", "spacecraft", "--ground", stub.url],
            *["--token", TOKEN, "--time-scale", str(SCALE), *args],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )

        def seen() -> bool:
            last = max((f.generation_time_ns for f in stub.frames.values()), default=0)
            return bool(stub.hellos) and last > stub.hellos[0].onboard_time_ns + 6 * 10**9

        await stub.wait_for(seen, timeout_s=30.0)
        proc.send_signal(signal.SIGTERM)
        _, err = await asyncio.wait_for(proc.communicate(), timeout=40.0)
        assert proc.returncode == 0, err.decode()
        await stub.stop()
        return stub

    stub = asyncio.run(main())
    records = [json.loads(line) for line in truth.read_text().splitlines()]
    start = records[0]
    assert start["event"] == "start" and start["safing"] is safing
    assert start["faults"] == ["attitude-bias@2,deg=5,axis=x"]
    assert records[1]["event"] == "fault"
    assert records[1]["onboard_time_ns"] == start["onboard_time_ns"] + 2 * 10**9
    reports = [m for m in stub.other if isinstance(m, Safing)]
    if safing:
        assert records[2]["event"] == "safing_entry"
        assert reports and reports[0].since_time_ns == records[2]["onboard_time_ns"]
    else:
        assert [r["event"] for r in records[2:]] == ["link"] and not reports
        frames = [
            f for f in stub.frames.values() if f.generation_time_ns > records[1]["onboard_time_ns"]
        ]
        quat = np.array([f.quat_orbit_from_base_xyzw for f in frames])
        target = np.array([f.acs_target_quat_xyzw for f in frames])
        assert np.max(np.abs(attitude_error_deg(quat, target))) > 4.5  # seen, not acted on
