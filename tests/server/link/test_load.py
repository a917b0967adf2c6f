"""A live pass under 80 concurrent viewer reads: 10 viewer tokens with 8 clients each (past
a token's 6 heavy reads and the viewers' 16 at once: both caps turn viewers away) loop over
the heaviest reads of an imported, analysed pass (its recording, the report as JSON and
HTML, its analyses, raw telemetry: a PTP pass of 5,000 frames, the raw telemetry read's
whole page) while the ground flies a pass at 20x, then aborts a second one; the viewers go
on until both caps have turned away a share of them (:data:`REFUSED_AT_LEAST`), then stop
(their reads in flight cut once every kind of read has completed). Meanwhile
an operator's screen samples liveness and the link status and keeps a console websocket
open (it connects while the load is on).

Everything is a real process on loopback: ``hikoboshi serve`` (so the load in this process
does not share the server's interpreter), ``hikoboshi spacecraft`` at 20x, and the clients
here (tests/server/link/load.py, shared with bench/bench_load.py). The viewers do as the API
tells them: a 429 or 503 is waited out for its ``Retry-After``.

Asserted: the outcomes (every command executed at its tag, no frame missing, the console
connected and never dropped, viewers answered only 200, 429, 503 or 504, the abort done,
the server's memory bounded) and, on latencies, only a lock-out guard (:data:`LOCKOUT_S`;
the defect was health and the link status at 12-15 s and a console that could not connect)
and on the ingest a lag guard in frames (:data:`LAG_GUARD_FRAMES`; the defect was a
backlog growing all pass long, 25 s behind on PostgreSQL).
What they are under this load against no load: ``bench/bench_load.py``.

The load saturates both cores on purpose; no other real-time test runs beside it (the
``realtime`` group, tests/conftest.py): their margins are tens of milliseconds of wall.
On PostgreSQL only (the backend whose ingest fell behind under this load: the defect); the
same load on SQLite is ``bench/bench_load.py``'s default (the suite ran both: 3 to 8 minutes
of its real-time chain with one core busy).
"""

from __future__ import annotations

import asyncio
import io
import sys
import time
from pathlib import Path

import httpx
import pytest

from planner.dynamics import DynamicsWorkspace
from planner.experiments import PtpParams, plan_ptp
from planner.model import default_model
from server.services.summary import pass_summary
from server.storage import repository as repo
from server.storage.db import make_engine, read_session_factory, session_factory
from spacecraft.offline import fly_offline
from telemetry.mcap import write_mcap
from telemetry.recording import PassRecording
from tests.server.link.harness import serve_process, with_flight_rules
from tests.server.link.load import (
    OPERATOR_LIMITS,
    Probes,
    ViewerLoad,
    abort_mid_pass,
    fly,
    peak_rss_bytes,
    spacecraft_process,
    stored_pass,
    until,
    viewer_answers,
    viewer_process,
)
from tests.support.processes import free_port

pytestmark = pytest.mark.realtime  # flies a vehicle or serves a live link in wall time

SCALE = 20.0
OPERATOR_TOKEN = "operator-token-0123456789"
SPACECRAFT_TOKEN = "spacecraft-token-01234567"
#: 80 viewers, past both caps; the issue's 200 (20 x 10) are bench/bench_load.py's, which
#: reports the latencies under them against no load
VIEWER_TOKENS = [f"viewer-token-{k:02d}-0123456789" for k in range(10)]
CLIENTS_PER_TOKEN = 8
TOKENS = ",".join(
    [f"{OPERATOR_TOKEN}=otto:operator", f"{SPACECRAFT_TOKEN}=ets7:spacecraft"]
    + [f"{token}=viewer{k:02d}:viewer" for k, token in enumerate(VIEWER_TOKENS)]
)
OPERATOR = {"Authorization": f"Bearer {OPERATOR_TOKEN}"}
#: A lock-out guard, not a target: health, the link status, the console's handshake and
#: pings and the abort each answer within this under the load (they took 12-15 s before
#: the lanes; the targets, 1 s at p99, are the benchmark's).
LOCKOUT_S = 10.0
#: The vehicle's telemetry rate (onboard Hz: spacecraft/vehicle_config.py's 0.1 s period).
FRAME_RATE_HZ = 10.0
#: A lag guard, in frames, not the target: the ground holds every frame but at most the
#: lock-out guard's worth of the pass at its time scale (2,000 frames, 100 s onboard).
#: The defect was a backlog that grew for the whole pass (25 s behind at 20x on
#: PostgreSQL: 5,000 frames, the ingest waiting behind the command stages' writes); the
#: target, 2 s (400 frames), is the benchmark's.
LAG_GUARD_FRAMES = int(LOCKOUT_S * SCALE * FRAME_RATE_HZ)
#: The server process's peak resident set (VmHWM): its own, the heavy work runs in worker
#: processes each bounded by RLIMIT_AS.
SERVER_RSS_BOUND = 768 * 1024 * 1024
#: The caps shown at work: the viewers keep loading (past the passes, if need be) until
#: this many were refused by each, 429 past a token's heavy reads (8 clients a token
#: against its 6) and 503 past the viewers' share (80 against 16); a guard against a load
#: that never reached the caps (:data:`CAPS_GUARD_S`).
REFUSED_AT_LEAST = {429: 20, 503: 20}
CAPS_GUARD_S = 120.0


#: Every kind of read the viewers make (a route's last part): each was read whole (the
#: viewers stop once each has been, their other reads in flight cut).
READS = {"recording.mcap", "report.html", "report", "analyses", "telemetry"}


def _caps_refused(answers: dict[int, int]) -> bool:
    return all(answers.get(status, 0) >= n for status, n in REFUSED_AT_LEAST.items())


@pytest.fixture(scope="module")
def viewed_recording() -> PassRecording:
    """What the viewers read: a PTP pass (joints 1 and 4 by 10 degrees, then 490 s at rest)
    flown offline, 5,000 frames: the raw telemetry read's whole page (``limit=5000``), a
    third of the demo pass (whose plan and flight took 17 s and its import and analyses 18
    s more; the reads are as many, each shorter)."""
    plan = plan_ptp(
        DynamicsWorkspace(default_model()),
        PtpParams(goal_joints_deg=(10.0, 0.0, 0.0, 10.0, 0.0, 0.0), settle_s=490.0),
    )
    plan = with_flight_rules(plan)
    flight = fly_offline(plan, seed=7)
    assert not flight.rejected, flight.rejected[:3]
    return PassRecording.from_frames(
        "viewed", plan, flight.epoch_ns, flight.frames, meta={"source": "offline flight, seed 7"}
    )


@pytest.mark.slow
def test_a_pass_flies_and_its_operators_keep_control_under_80_concurrent_viewer_reads(
    postgres_schema_url: str, tmp_path: Path, viewed_recording: PassRecording
) -> None:
    database_url = postgres_schema_url
    buffer = io.BytesIO()
    write_mcap(viewed_recording, buffer)
    assert len(viewed_recording.frames) >= 5000
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    engine = make_engine(database_url)
    sessions = session_factory(engine)
    readers = read_session_factory(engine)  # polling takes no write lock on SQLite
    env = {"HIKOBOSHI_TOKENS": TOKENS, "HIKOBOSHI_DATA_DIR": str(tmp_path / "data")}
    spacecraft_log = tmp_path / "spacecraft.log"

    async def scenario(server_pid: int) -> tuple[ViewerLoad, Probes, str, str, float, int]:
        probes = Probes(base, OPERATOR_TOKEN)
        t0 = time.monotonic()

        def mark(what: str) -> None:
            print(f"{time.monotonic() - t0:6.1f} s: {what}", file=sys.stderr)

        async with httpx.AsyncClient(
            base_url=base, timeout=300.0, headers=OPERATOR, limits=OPERATOR_LIMITS
        ) as op:
            # the vehicle starts (a fresh interpreter) and the first pass is planned while
            # the viewers' pass is imported and analysed (the second is planned between
            # the passes, as an operator would, which lets the ground's writes catch up)
            vehicle = spacecraft_process(port, SPACECRAFT_TOKEN, SCALE, spacecraft_log)
            planned = asyncio.create_task(asyncio.to_thread(stored_pass, sessions, "loaded", 230.0))
            try:
                response = await op.post("/api/passes/import", content=buffer.getvalue())
                assert response.status_code == 201, response.text
                demo_id = response.json()["imported"]["id"]
                response = await op.post(f"/api/passes/{demo_id}/analyses")
                assert response.status_code == 201, response.text
                mark("imported and analysed")
                # the viewers in a process of their own: the probes here time the server
                answers = tmp_path / "viewers.json"
                with viewer_process(
                    base, VIEWER_TOKENS, CLIENTS_PER_TOKEN, demo_id, answers
                ) as load:
                    while not (await op.get("/api/link/status")).json()["connected"]:
                        assert vehicle.poll() is None, spacecraft_log.read_text()[-2000:]
                        await asyncio.sleep(0.1)
                    # the load is on (the caps answering already) before the probes and
                    # the pass
                    await until(
                        lambda: sum(viewer_answers(answers).values()) >= len(VIEWER_TOKENS),
                        CAPS_GUARD_S,
                        "the viewers answered",
                    )
                    tasks = probes.start()
                    tasks.append(
                        asyncio.create_task(
                            probes.console(base.replace("http", "ws") + "/api/console")
                        )
                    )
                    try:
                        mark("console opening, first pass starting")
                        # 10 s of motion, then 230 s holding: 13 s of wall at 20x
                        flown = await fly(op, sessions, readers, "loaded", 230.0, await planned)
                        mark("first pass complete")
                        cut, answer, abort_s = await abort_mid_pass(op, sessions, readers, "cut")
                        assert answer.status_code == 200, answer.text
                        assert answer.json()["state"] == "aborted"
                        mark("second pass aborted and resolved")
                        await until(
                            lambda: _caps_refused(viewer_answers(answers)),
                            CAPS_GUARD_S,
                            f"the caps refused viewers {REFUSED_AT_LEAST}",
                        )
                        mark(f"the caps refused viewers: {viewer_answers(answers)}")
                    finally:
                        probes.stop.set()
                        done = await asyncio.gather(*tasks, return_exceptions=True)
                    peak = peak_rss_bytes(server_pid)
                errors = [r for r in done if isinstance(r, BaseException)]
                assert not errors, errors[:3]
            finally:
                vehicle.terminate()
                vehicle.wait(timeout=30)
        return load, probes, flown, cut, abort_s, peak

    try:
        with serve_process(database_url, port, tmp_path / "server.log", env) as server:
            load, probes, flown, cut, abort_s, peak = asyncio.run(scenario(server.pid))
        with sessions() as session:
            commands = repo.list_commands(session=session, pass_id=flown)
            summary = pass_summary(session=session, pass_id=flown)
            cut_commands = repo.list_commands(session=session, pass_id=cut)
            deleted = repo.list_events(session=session, pass_id=cut, kinds=["schedule_deleted"])
    finally:
        engine.dispose()

    lag = probes.ingest_lag()
    print(
        f"abort {abort_s:.3f} s, health max {max(probes.health_s):.3f} s, link max "
        f"{max(probes.link_s):.3f} s, console open {probes.console_open_s} s, pings max "
        f"{max(probes.console_pings_s, default=None)} s, lag {lag}, peak RSS "
        f"{peak / 2**20:.0f} MiB, viewers {load.status} {load.codes} {load.complete}"
    )
    # the pass flew untouched: every command executed at its tag, no frame missing
    assert len(commands) > 900
    assert {c.stage for c in commands} == {"executed"}
    assert all(c.executed_at_ns == c.execute_time_ns for c in commands)
    assert summary.frames_missing == 0 and summary.gaps_open == 0
    assert summary.commands_expired == 0
    # the ground kept up with the vehicle's telemetry throughout (sampled in both passes)
    assert len(probes.link) >= 20, len(probes.link)
    assert lag["frames_behind_max"] is not None and lag["frames_behind_max"] < LAG_GUARD_FRAMES, lag
    # the load was real: every kind of read completed, and the caps turned viewers away
    # (429 past a token's heavy reads, 503 past the viewers' share); on a machine busy
    # with other work a download can outlive its read deadline: 504 deadline_exceeded
    assert set(load.status) <= {200, 429, 503, 504}, (load.status, load.codes)
    assert set(load.codes) <= {"429 too_many_requests", "503 busy", "504 deadline_exceeded"}
    assert set(load.complete) == READS
    assert _caps_refused(load.status), load.status
    assert load.stale_connections <= max(3, sum(load.status.values()) // 20), load
    # the operator's screen: liveness and link status always answered, never locked out
    assert not probes.unexpected, probes.unexpected
    assert len(probes.health_s) >= 20 and max(probes.health_s) < LOCKOUT_S
    assert len(probes.link_s) >= 20 and max(probes.link_s) < LOCKOUT_S
    # a console opened under the load, followed the passes and never dropped
    assert probes.console_open_s is not None and probes.console_open_s < LOCKOUT_S
    assert probes.console_dropped is None, probes.console_dropped
    assert probes.console_messages["link"] >= 3 and probes.console_messages["event"] >= 10
    assert len(probes.console_pings_s) >= 20 and max(probes.console_pings_s) < LOCKOUT_S
    # the abort was done; nothing of the cut pass was lost or left open
    assert abort_s < LOCKOUT_S, f"abort answered in {abort_s:.2f} s"
    assert {c.stage for c in cut_commands} <= {"executed", "cancelled"}
    # and it stopped the pass on board: nothing executed from the delete's tag on, and
    # everything before it did (a stage set alone would not tell a pass that ran on)
    [delete] = deleted.items
    from_ns = int(delete.detail["from_time_ns"])
    later = [c for c in cut_commands if c.execute_time_ns >= from_ns]
    earlier = [c for c in cut_commands if c.execute_time_ns < from_ns]
    ran_on = [
        (c.seq, c.stage, c.execute_time_ns - from_ns) for c in later if c.stage != "cancelled"
    ]
    assert later and not ran_on, (len(later), len(ran_on), ran_on[:5])
    assert earlier and {c.stage for c in earlier} == {"executed"}, len(earlier)
    assert peak < SERVER_RSS_BOUND, f"server peak RSS {peak / 2**20:.0f} MiB"
