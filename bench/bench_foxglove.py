"""The Foxglove live view's cost on telemetry ingest, as a ratio (with / without).

The ingest loop of the ground's downlink, in this process: each message's frames are stored
(``repository.ingest_frames``, one transaction per message, SQLite in a temporary
directory) and then handed to the publisher (``Publisher.publish_frames``, what the
downlink does once they have committed). The frames: a flown PTP pass (the real vehicle,
offline), 8 frames a message (2 s at 4 Hz).

Two runs, alternating, best of ``REPEAT`` each:

- without: nobody subscribed to the publisher's frames;
- with: :class:`server.services.foxglove_live.FoxgloveLive` listening on a free port with
  one client (the tests' protocol client, in a process of its own) subscribed to its
  channels: its
  callback queues each message, its thread makes and sends ``/tf``, the plots and the
  scene while the loop goes on (competing for the GIL: the cost that shows here).

Figures: frames per second each way, the ratio ``with / without`` (1.0: no cost), and what
the view sent and dropped (drop-oldest queue of ``QUEUE_ITEMS`` messages) in the last run.
Target: ratio >= 0.8 (the view may not take a fifth of ingest; its thread works at most
``MAX_DUTY`` of the time, so at this flood rate it drops: counted, as it must).

Run: ``.venv/bin/python bench/bench_foxglove.py`` (needs the foxglove extra).
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout first

from _common import emit

from planner.dynamics import DynamicsWorkspace
from planner.experiments import PtpParams, plan_ptp
from planner.model import default_model
from server.services.dbworker import Publisher
from server.services.foxglove_live import QUEUE_ITEMS, FoxgloveLive
from server.storage import repository as repo
from server.storage.db import (
    make_engine,
    read_session_factory,
    session_factory,
    sqlite_url,
    upgrade,
)
from spacecraft.offline import fly_offline
from telemetry.wire import TelemetryFrame

ROOT = Path(__file__).resolve().parents[1]
PER_MESSAGE = 8
REPEAT = 3


def _frames() -> tuple[Any, list[TelemetryFrame], int]:
    plan = plan_ptp(
        DynamicsWorkspace(default_model()), PtpParams(goal_joints_deg=(20, -10, 0, 15, 0, 0))
    )
    flight = fly_offline(plan, after_s=20.0)
    return plan, list(flight.frames), int(flight.epoch_ns)


def _pass(sessions: Any, plan: Any, epoch_ns: int, name: str) -> str:
    with sessions() as session:
        plan_record = repo.add_plan(session=session, plan=plan, created_at_ns=epoch_ns)
        record = repo.add_pass(
            session=session,
            name=name,
            plan_id=plan_record.id,
            aos_time_ns=epoch_ns,
            los_time_ns=epoch_ns + 3600 * 10**9,
            relay="TDRS-W",
            created_at_ns=epoch_ns,
        )
        record.epoch_ns = epoch_ns
        session.commit()
        return str(record.id)


def _ingest(
    sessions: Any, publisher: Publisher, pass_id: str, frames: list[TelemetryFrame]
) -> float:
    start = time.perf_counter()
    for k in range(0, len(frames), PER_MESSAGE):
        batch = frames[k : k + PER_MESSAGE]
        now = time.time_ns()
        with sessions() as session:
            repo.ingest_frames(
                session=session, pass_id=pass_id, frames=batch, reception_time_ns=now
            )
            session.commit()
        publisher.publish_frames(pass_id, batch, now)
    return time.perf_counter() - start


def _client(port: int) -> subprocess.Popen[str]:
    """The tests' protocol client in a process of its own, subscribed to every channel."""
    topics = ["/tf", "/events", "/scene", "/robot_description", "/plot/joints", "/plot/base"]
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "tests.server.link.foxglove_client",
            f"ws://127.0.0.1:{port}",
            *topics,
        ],
        cwd=ROOT,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None
    assert proc.stdout.readline().strip() == "subscribed"
    return proc


def main() -> None:
    plan, frames, epoch_ns = _frames()
    with tempfile.TemporaryDirectory() as folder:
        url = sqlite_url(Path(folder))
        engine = make_engine(url)
        upgrade(engine)
        sessions = session_factory(engine)
        readers = read_session_factory(engine)
        without: list[float] = []
        with_view: list[float] = []
        sent = dropped = received_tf = 0
        for run in range(REPEAT):
            publisher = Publisher()
            without.append(
                _ingest(sessions, publisher, _pass(sessions, plan, epoch_ns, f"a{run}"), frames)
            )

            publisher = Publisher()
            live = FoxgloveLive(host="127.0.0.1", port=0, publisher=publisher, sessions=readers)
            live.start()
            client = _client(live.port)
            pass_id = _pass(sessions, plan, epoch_ns, f"b{run}")
            with_view.append(_ingest(sessions, publisher, pass_id, frames))
            deadline = time.monotonic() + 30.0
            while not live.idle() and time.monotonic() < deadline:  # let it finish to count
                time.sleep(0.05)
            time.sleep(1.0)  # the SDK's own send queue to the client
            sent, dropped = live.sent, live.dropped
            out, _ = client.communicate("", timeout=60)
            received_tf = json.loads(out.strip().splitlines()[-1]).get("/tf", 0)
            live.close()
        engine.dispose()
    fps_without = len(frames) / min(without)
    fps_with = len(frames) / min(with_view)
    ratio = fps_with / fps_without
    emit(
        "foxglove_live",
        {
            "frames": len(frames),
            "frames_per_message": PER_MESSAGE,
            "ingest_fps_without": round(fps_without, 1),
            "ingest_fps_with": round(fps_with, 1),
            "ratio_with_over_without": round(ratio, 3),
            "queue_items": QUEUE_ITEMS,
            "last_run_sent": sent,
            "last_run_dropped": dropped,
            "last_run_client_tf": received_tf,
        },
        {"ratio_at_least_0.8": ratio >= 0.8},
    )


if __name__ == "__main__":
    main()
