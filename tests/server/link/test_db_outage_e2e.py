"""PostgreSQL goes away mid-pass and comes back (a proxy in front of the real server cuts
every connection and refuses new ones): the ground keeps flying from memory, shows the
outage, stops sending once its command lease lapses (the vehicle flies what it holds),
replays its journal in order when the database answers, and the pass completes: every
command's stage final and the vehicle's own record, every frame of the pass stored once
(docs/operations.md "A database outage"). Other lengths: ``HIKOBOSHI_TEST_OUTAGE_S``."""

from __future__ import annotations

import asyncio
import os
import time
from typing import Any

import httpx
import pytest

from server.storage import repository as repo
from server.storage.db import make_engine, read_session_factory
from tests.server.cut_proxy import cut_proxy
from tests.server.link.harness import (
    VIEWER,
    assert_every_frame_once,
    assert_stages_are_the_vehicles,
    connected,
    executed_on_board,
    pass_resolved,
    running_ground,
    spacecraft,
    start_pass,
    store_pass,
    wait_for,
)
from tests.support.flight import flying

pytestmark = pytest.mark.realtime

#: wall s the database is away: 200 s onboard at the harness's 10x, past the lead window and
#: across the pass's LOS (the commands never sent expire while the lease lapses; with 6 s,
#: inside the lead window and before LOS, a bug that left them queued for good went unseen)
OUTAGE_S = float(os.environ.get("HIKOBOSHI_TEST_OUTAGE_S", "20"))


@pytest.mark.slow
def test_a_pass_rides_a_database_outage_through(postgres_schema_url: str) -> None:
    with (
        cut_proxy(postgres_schema_url) as (proxy, through),
        running_ground(through, lease_ttl_s=3.0, lease_renew_s=0.5) as ground,
    ):
        engine = make_engine(postgres_schema_url)  # the test's own reads: not through it
        readers = read_session_factory(engine)
        pass_id = store_pass(ground.sessions, "outage", (10.0, 0.0, 0.0, 10.0, 0.0, 0.0), 150.0)
        process, generated = spacecraft(ground)

        def on_board_30() -> bool:
            return executed_on_board(readers, process, pass_id, 30)

        def ended() -> bool:
            return pass_resolved(readers, pass_id)

        seen: dict[str, Any] = {}

        async def scenario() -> None:
            async with (
                flying(process, drain_s=60.0) as land,
                httpx.AsyncClient(base_url=ground.url, timeout=30.0) as client,
            ):
                await connected(client)
                await start_pass(client, pass_id, "outage")
                await wait_for(on_board_30, 60.0, "30 commands executed")
                proxy.cut()
                cut_at = time.monotonic()
                db = ground.app.state.db
                await wait_for(lambda: db.outage.down_since is not None, 30.0, "the outage")
                # the link's status (no database needed) shows it to the consoles
                status = (await client.get("/api/link/status", headers=VIEWER)).json()
                assert status["ground"]["database"]["reachable"] is False
                authority = ground.app.state.authority
                await wait_for(lambda: not authority.may_command(), 30.0, "lease lapsing")
                status = (await client.get("/api/link/status", headers=VIEWER)).json()
                assert status["ground"]["command"]["commanding"] is False
                seen["journal_during"] = db.journal
                await asyncio.sleep(max(0.0, OUTAGE_S - (time.monotonic() - cut_at)))
                proxy.restore()
                await wait_for(ended, 180.0, "the pass ended, resolved")
                metrics = (await client.get("/metrics", headers=VIEWER)).text
                assert "hikoboshi_database_reachable 1.0" in metrics
                assert "hikoboshi_database_outages_total 1.0" in metrics
                summary = await client.get(f"/api/passes/{pass_id}/summary", headers=VIEWER)
                assert summary.status_code == 200, summary.text
                seen["summary"] = summary.json()
                seen["outage"] = db.outage.status(db.journal)
                await land()
                assert process.store.unacked == 0

        try:
            asyncio.run(scenario())
            with readers() as session:
                commands = repo.list_commands(session=session, pass_id=pass_id)
                record = repo.get_pass(session=session, pass_id=pass_id)
                frames = repo.frame_seqs(session=session, pass_id=pass_id)
        finally:
            engine.dispose()
    assert_stages_are_the_vehicles(commands, process)  # every stage final, the vehicle's
    assert all(c.stage in ("executed", "expired") for c in commands)
    summary, outage = seen["summary"], seen["outage"]
    assert summary["commands_unresolved"] == summary["commands_cancelled"] == 0
    assert record.state == "complete", (record.state, record.state_reason)
    assert_every_frame_once(record, frames, generated)
    assert outage["outages"] == 1 and outage["last_down_s"] >= OUTAGE_S * 0.9
    print(
        f"database away {outage['last_down_s']:.1f} s; journal {seen['journal_during']} "
        f"during, peak {outage['journal_peak']}, replayed in {outage['last_replay_s'] or 0:.1f} s; "
        f"{summary['outcome_text']}"
    )
