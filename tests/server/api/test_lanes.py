"""Capacity lanes (server/api/lanes.py): viewers' requests in flight are capped (503
``busy``), heavy reads per token (429 ``too_many_requests``), and neither cap nor the
readers' database pool touches liveness, the link status, an operator's requests or the
consoles.

Requests are held in flight for real: the readers' pool has one connection, which the test
holds, so a viewer's read waits for it (up to the pool's timeout) in a thread of its own;
the test waits on the edge's counters, never on time."""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import httpx
from fastapi.testclient import TestClient
from sqlalchemy import Engine, text

from server.api.lanes import HEAVY_ROUTES, Admission, Lane, Refusal, Ticket, is_heavy, lane_of
from server.app import create_app
from server.settings import ApiToken, Role, Settings
from server.storage.db import READ_ONLY_OPTION
from tests.support.api import OPERATOR, TOKENS, VIEWER, add_pass

VIC = {"Authorization": "Bearer v2-token"}


def test_the_lane_and_heaviness_of_a_request_come_from_its_path_and_role() -> None:
    assert lane_of("/api/health", None) is Lane.LIVE
    assert lane_of("/api/link/status", Role.VIEWER) is Lane.LIVE
    assert lane_of("/api/console", Role.VIEWER) is Lane.LIVE
    assert lane_of("/api/passes", Role.OPERATOR) is Lane.OPERATOR
    assert lane_of("/api/passes", Role.VIEWER) is Lane.VIEWER
    assert is_heavy("GET", "/api/passes/abc/recording.mcap")
    assert is_heavy("HEAD", "/api/passes/abc/report.html")
    assert is_heavy("GET", "/api/passes/abc/report/figures/residuals.png")
    assert is_heavy("POST", "/api/passes/abc/analyses")
    assert not is_heavy("GET", "/api/passes/abc/analyses")  # the stored results: light
    assert not is_heavy("GET", "/api/passes/abc/report/extra")
    assert not is_heavy("GET", "/api/passes/abc")


def test_every_heavy_route_is_served_by_the_application(tmp_path: Path) -> None:
    """A renamed route would silently leave the per-token limit: the table must name real
    routes and methods."""
    schema = create_app(Settings(data_dir=tmp_path)).openapi()
    for method, template in HEAVY_ROUTES:
        assert method.lower() in schema["paths"].get(template, {}), (method, template)


def test_a_refused_request_holds_nothing_and_a_ticket_is_released_once() -> None:
    async def scenario() -> Admission:
        admission = Admission(viewer_requests_max=1, heavy_reads_per_token=1)
        first = await admission.admit(Lane.VIEWER, heavy=True, holder="vera")
        assert isinstance(first, Ticket)
        refused = await admission.admit(Lane.VIEWER, heavy=True, holder="vera")
        assert isinstance(refused, Refusal) and refused.status == 429
        refused = await admission.admit(Lane.VIEWER, heavy=False, holder="vic")
        assert isinstance(refused, Refusal) and refused.status == 503  # no queue
        operator = await admission.admit(Lane.OPERATOR, heavy=False, holder="otto")
        assert isinstance(operator, Ticket)
        assert admission.viewers_in_flight == 1 and admission.heavy_in_flight == {"vera": 1}
        first.release()
        first.release()
        operator.release()
        assert admission.viewers_in_flight == 0 and not admission.heavy_in_flight
        return admission

    assert asyncio.run(scenario()).refused == {"too_many_requests": 1, "busy": 1}


def test_waiting_viewers_get_places_in_turn_and_give_up_at_their_wait() -> None:
    async def scenario() -> None:
        admission = Admission(
            viewer_requests_max=1, heavy_reads_per_token=2, viewer_queue=2, viewer_queue_wait_s=30
        )
        running = await admission.admit(Lane.VIEWER, heavy=False, holder="vera")
        assert isinstance(running, Ticket)
        second = asyncio.create_task(admission.admit(Lane.VIEWER, heavy=True, holder="vic"))
        third = asyncio.create_task(admission.admit(Lane.VIEWER, heavy=False, holder="vic"))
        while admission.viewers_waiting < 2:
            await asyncio.sleep(0)
        assert admission.heavy_in_flight == {"vic": 1}  # a waiting heavy read counts
        full = await admission.admit(Lane.VIEWER, heavy=False, holder="val")
        assert isinstance(full, Refusal) and full.code == "busy"  # the queue is full
        second.cancel()  # a client gone while waiting gives its turn up
        running.release()  # the place goes to the next in turn, not back to the pool
        ticket = await third
        assert isinstance(ticket, Ticket) and second.cancelled()
        assert admission.viewers_in_flight == 1 and not admission.heavy_in_flight
        ticket.release()
        assert admission.viewers_in_flight == 0 and admission.viewers_waiting == 0
        # a wait that runs out is refused busy and holds nothing
        admission.viewer_queue_wait_s = 0.01
        held = await admission.admit(Lane.VIEWER, heavy=False, holder="vera")
        late = await admission.admit(Lane.VIEWER, heavy=True, holder="vic")
        assert isinstance(late, Refusal) and late.status == 503
        assert admission.viewers_in_flight == 1 and not admission.heavy_in_flight
        assert isinstance(held, Ticket)
        held.release()
        assert admission.viewers_in_flight == 0

    asyncio.run(scenario())


@contextmanager
def _held_readers_pool(engine: Engine) -> Iterator[None]:
    with engine.execution_options(**{READ_ONLY_OPTION: True}).connect() as held:
        held.execute(text("SELECT 1"))
        yield


def _until(predicate: Callable[[], bool], what: str) -> None:
    deadline = time.monotonic() + 30.0
    while not predicate():
        assert time.monotonic() < deadline, what
        time.sleep(0.01)


def test_viewers_past_their_caps_are_refused_while_live_and_operator_lanes_go_on(
    database_url: str, tmp_path: Path
) -> None:
    tokens = {**TOKENS, "v2-token": ApiToken(name="vic", role=Role.VIEWER)}
    settings = Settings(
        data_dir=tmp_path,
        database_url=database_url,
        tokens=tokens,
        api_pool_size=1,
        api_pool_overflow=0,
        api_pool_timeout_s=30.0,
        viewer_requests_max=2,
        viewer_queue=1,
        viewer_queue_wait_s=60.0,
        heavy_reads_per_token=1,
    )
    with TestClient(create_app(settings)) as client:
        app = client.app
        pass_id = add_pass(client, "lanes")
        admission: Admission = app.state.admission  # type: ignore[attr-defined]
        answers: dict[str, httpx.Response] = {}

        def get(name: str, path: str, headers: dict[str, str]) -> threading.Thread:
            def run() -> None:
                answers[name] = client.get(path, headers=headers)

            thread = threading.Thread(target=run)
            thread.start()
            return thread

        with _held_readers_pool(app.state.engine):  # type: ignore[attr-defined]
            # vera's heavy read (a bucketed telemetry read) waits for the readers' pool
            held = [get("heavy", f"/api/passes/{pass_id}/telemetry?buckets=4", VIEWER)]
            _until(lambda: admission.heavy_in_flight["vera"] == 1, "vera's heavy read")
            response = client.get(f"/api/passes/{pass_id}/report", headers=VIEWER)
            assert response.status_code == 429, response.text
            assert response.json()["error"]["code"] == "too_many_requests"
            assert response.headers["retry-after"] == "5"
            # vic's light read fills the viewers' cap; the next viewer request is refused
            held.append(get("light", "/api/passes", VIC))
            _until(lambda: admission.viewers_in_flight == 2, "two viewer requests")
            # the next waits its turn (parked: no thread); one more finds the queue full
            held.append(get("queued", f"/api/passes/{pass_id}", VIC))
            _until(lambda: admission.viewers_waiting == 1, "a viewer request waiting")
            response = client.get(f"/api/passes/{pass_id}/summary", headers=VIC)
            assert response.status_code == 503, response.text
            assert response.json()["error"]["code"] == "busy"
            assert response.json()["error"]["detail"] == {"retry_after_s": 1}
            assert response.headers["retry-after"] == "1"
            # liveness and the link status: no cap, no thread, no database
            assert client.get("/api/health").status_code == 200
            response = client.get("/api/link/status", headers=VIEWER)
            assert response.status_code == 200 and response.json()["connected"] is False
            # an operator's reads: their own lane and pool (the readers' is held)
            response = client.get(f"/api/passes/{pass_id}/commands", headers=OPERATOR)
            assert response.status_code == 200, response.text
            # a console (a viewer's too) connects and its hub reads on its own connections
            with client.websocket_connect("/api/console", headers=VIEWER) as ws:
                assert ws.receive_json()["type"] == "welcome"
                ws.send_json(
                    {"v": 1, "type": "subscribe", "topic": "telemetry", "pass_id": pass_id}
                )
                reply = ws.receive_json()
                assert (reply["type"], reply["pass_id"]) == ("subscribed", pass_id), reply
            # and the abort, the control path
            response = client.post(
                f"/api/passes/{pass_id}/abort",
                json={"confirm": "ABORT lanes", "reason": "lanes test"},
                headers=OPERATOR,
            )
            assert response.status_code == 200, response.text
            assert (admission.viewers_in_flight, admission.viewers_waiting) == (2, 1)
        for thread in held:
            thread.join(timeout=30.0)
        assert answers["heavy"].status_code == 200, answers["heavy"].text
        assert answers["light"].status_code == 200, answers["light"].text
        assert answers["queued"].status_code == 200, answers["queued"].text
        assert admission.viewers_in_flight == 0 and not admission.heavy_in_flight
        assert client.get(f"/api/passes/{pass_id}/report", headers=VIEWER).status_code != 429
