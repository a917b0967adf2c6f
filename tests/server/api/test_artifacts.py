"""A pass's heavy artifacts (recording, report, report page, figures) are computed once per
content version and served from the stored file (server/services/artifacts.py), on SQLite
and PostgreSQL: a second request starts no worker job, concurrent ones share one, a change
of content gives a new version and new bytes equal to the uncached computation, a failed
job is not stored, ``If-None-Match`` answers 304, and the bytes kept stay within
``artifact_cache_bytes``. Jobs are counted on the real pool (``WorkerPool.started``); waits
are on state, with generous guards."""

from __future__ import annotations

import functools
import io
import time
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from sqlalchemy.orm import Session

from server.app import create_app
from server.services import analyses as analyses_service
from server.services import recordings as recordings_service
from server.services import reports as reports_service
from server.services.artifacts import ArtifactStore
from server.services.clock import ManualClock
from server.services.command_stages import set_command_stage
from server.services.workers import WorkerPool
from server.settings import Settings
from server.storage import fingerprints
from server.storage import repository as repo
from server.storage.db import make_engine, read_session_factory
from telemetry.mcap import read_mcap
from tests.server.storage.factories import make_commands
from tests.support.api import OPERATOR, TOKENS, VIEWER, add_pass, sessions

#: A guard against a hang, not a timing assertion: a loaded 2-core machine may be slow.
PATIENCE_S = 60.0


def _wait_for(condition: Callable[[], bool], what: str) -> None:
    deadline = time.monotonic() + PATIENCE_S
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.02)


@contextmanager
def _app(database_url: str, tmp_path: Path, **settings: Any) -> Iterator[TestClient]:
    config = Settings(data_dir=tmp_path, database_url=database_url, tokens=TOKENS, **settings)
    with TestClient(create_app(config)) as client:
        pool = _pool(client)
        # the warm-up job has come and gone: what is counted from here is ours
        _wait_for(lambda: pool.admitted == 0 and pool.started >= 1, "the warm-up job")
        yield client


def _pool(client: TestClient) -> WorkerPool:
    pool: WorkerPool = client.app.state.workers  # type: ignore[attr-defined]
    return pool


def _store(client: TestClient) -> ArtifactStore:
    store: ArtifactStore = client.app.state.artifacts  # type: ignore[attr-defined]
    return store


def _hold(pool: WorkerPool) -> Callable[[], Any]:
    """A job that holds a worker 60 s, unless cancelled."""
    return functools.partial(pool.run, time.sleep, 60, deadline_s=120, what="hold")


def _hold_the_worker(client: TestClient, pool: WorkerPool) -> Future[Any]:
    """:func:`_hold` on the pool's one worker, started."""
    assert client.portal is not None
    before_hold = pool.started
    held = client.portal.start_task_soon(_hold(pool))
    # Started, not only running: a process counts as running while its start (a thread)
    # is still under way, and counted as started once it is (a loaded machine sampled
    # ``started`` in between, and the held job's start was counted as the computation's).
    _wait_for(lambda: pool.running == 1 and pool.started == before_hold + 1, "the held worker")
    return held


def _import(client: TestClient, data: bytes) -> str:
    response = client.post("/api/passes/import", content=data, headers=OPERATOR)
    assert response.status_code == 201, response.text
    return str(response.json()["imported"]["id"])


def _uncached(database_url: str, fn: Callable[..., Any], **kwargs: Any) -> Any:
    """``fn`` on a read session of its own: what the route computed before the store."""
    engine = make_engine(database_url)
    try:
        with read_session_factory(engine)() as session:
            return fn(session=session, **kwargs)
    finally:
        engine.dispose()


def _tag(response: Any) -> str:
    etag: str = response.headers["etag"]
    assert etag.startswith('"') and etag.endswith('"'), etag
    return etag


def _move(session: Session, pass_id: str, seq: int, stage: str, time_ns: int) -> None:
    set_command_stage(
        session,
        clock=ManualClock(),
        pass_id=pass_id,
        seq=seq,
        stage=stage,
        time_ns=time_ns,
        actor="ground",
    )
    session.commit()


def test_a_recording_is_computed_once_per_version_and_served_from_its_file(
    database_url: str,
    tmp_path: Path,
    short_mcap: bytes,
) -> None:
    with _app(database_url, tmp_path) as client:
        pass_id = _import(client, short_mcap)
        pool, store = _pool(client), _store(client)
        url = f"/api/passes/{pass_id}/recording.mcap"
        started = pool.started

        first = client.get(url, headers=VIEWER)
        assert first.status_code == 200, first.text
        assert pool.started == started + 1
        _, uncached = _uncached(database_url, recordings_service.recording_mcap, pass_id=pass_id)
        assert first.content == uncached
        assert first.headers["content-length"] == str(len(uncached))
        assert first.headers["content-type"] == "application/octet-stream"
        assert first.headers["content-disposition"] == 'attachment; filename="b_short_b_PTP.mcap"'
        etag = _tag(first)
        [stored] = store.stored()
        assert stored == tmp_path / "artifacts" / pass_id / f"recording-{etag[1:-1]}.mcap"
        assert stored.read_bytes() == uncached

        again = client.get(url, headers=VIEWER)
        assert (again.content, _tag(again)) == (uncached, etag)
        not_modified = client.get(url, headers={**VIEWER, "If-None-Match": f"W/{etag}, x"})
        assert not_modified.status_code == 304 and not_modified.content == b""
        assert _tag(not_modified) == etag
        assert pool.started == started + 1  # neither started a job

        # A command added to the pass, then moved forward: each a new version, new bytes.
        with sessions(client)() as session:
            repo.add_commands(
                session=session, pass_id=pass_id, commands=make_commands(1, first_seq=100),
                queued_at_ns=7,
            )  # fmt: skip
            session.commit()
        added = client.get(url, headers={**VIEWER, "If-None-Match": etag})
        assert added.status_code == 200 and _tag(added) != etag
        stages = {c.seq: c.stage for c in read_mcap(io.BytesIO(added.content)).commands}
        assert stages[100] == "queued"
        with sessions(client)() as session:
            before = fingerprints.commands_summary(session, pass_id)
            _move(session, pass_id, 100, "released", 8)
            assert fingerprints.commands_summary(session, pass_id) != before
        moved = client.get(url, headers={**VIEWER, "If-None-Match": _tag(added)})
        assert moved.status_code == 200 and _tag(moved) not in (etag, _tag(added))
        stages = {c.seq: c.stage for c in read_mcap(io.BytesIO(moved.content)).commands}
        assert stages[100] == "released"
        _, uncached = _uncached(database_url, recordings_service.recording_mcap, pass_id=pass_id)
        assert moved.content == uncached
        # only the newest version is kept
        assert [p.name for p in store.stored()] == [f"recording-{_tag(moved)[1:-1]}.mcap"]
        assert not stored.exists()
        assert pool.started == started + 3

        for path in ("nope", "00000000-0000-4000-8000-000000000000"):
            missing = client.get(f"/api/passes/{path}/recording.mcap", headers=VIEWER)
            assert missing.status_code == 404 and missing.json()["error"]["code"] == "not_found"
        assert pool.started == started + 3  # refused on the version's own read


def test_the_report_its_page_and_figures_are_computed_once_per_run_of_the_analyses(
    database_url: str,
    tmp_path: Path,
    short_mcap: bytes,
) -> None:
    with _app(database_url, tmp_path) as client:
        pass_id = _import(client, short_mcap)
        pool = _pool(client)
        started = pool.started
        report_url = f"/api/passes/{pass_id}/report"
        missing = client.get(report_url, headers=VIEWER)
        assert missing.status_code == 404
        assert missing.json()["error"]["code"] == "analysis_not_run"
        assert pool.started == started  # no job for that either

        def fetch_all() -> dict[str, Any]:
            report = client.get(report_url, headers=VIEWER)
            assert report.status_code == 200, report.text
            out = {"report": report, "page": client.get(f"{report_url}.html", headers=VIEWER)}
            for name in report.json()["figures"]:
                out[name] = client.get(f"{report_url}/figures/{name}.png", headers=VIEWER)
            return out

        def uncached(name: str) -> Any:
            if name == "report":
                doc = _uncached(database_url, reports_service.pass_report, pass_id=pass_id)
                return doc.model_dump(mode="json")
            if name == "page":
                html = _uncached(database_url, reports_service.pass_report_html, pass_id=pass_id)
                return html.encode("utf-8")
            return _uncached(database_url, analyses_service.figure_png, pass_id=pass_id, name=name)

        def check(responses: dict[str, Any]) -> None:
            for name, response in responses.items():
                assert response.status_code == 200, (name, response.text)
                assert response.headers["content-length"] == str(len(response.content))
                if name == "report":
                    assert response.json() == uncached(name)
                else:
                    assert response.content == uncached(name), name

        assert client.post(f"/api/passes/{pass_id}/analyses", headers=OPERATOR).status_code == 201
        after_run = pool.started
        first = fetch_all()
        check(first)
        assert len(first) >= 3  # the report, its page and at least one figure
        assert first["page"].headers["content-type"] == "text/html; charset=utf-8"
        assert "img-src data:" in first["page"].headers["content-security-policy"]
        assert pool.started == after_run + len(first)  # one job each
        second = fetch_all()
        assert {k: (r.content, _tag(r)) for k, r in second.items()} == {
            k: (r.content, _tag(r)) for k, r in first.items()
        }
        for name, response in first.items():
            path = report_url + {"report": "", "page": ".html"}.get(name, f"/figures/{name}.png")
            again = client.get(path, headers={**VIEWER, "If-None-Match": _tag(response)})
            assert again.status_code == 304, name
        assert pool.started == after_run + len(first)  # none computed again

        # The analyses run again: a new version of each, with the new run's bytes.
        assert client.post(f"/api/passes/{pass_id}/analyses", headers=OPERATOR).status_code == 201
        after_rerun = pool.started
        rerun = fetch_all()
        check(rerun)
        for name in ("report", "page"):
            assert _tag(rerun[name]) != _tag(first[name])
            assert rerun[name].content != first[name].content  # the run's time is in it
        figure = next(k for k in rerun if k not in ("report", "page"))
        assert _tag(rerun[figure]) != _tag(first[figure])
        assert pool.started == after_rerun + len(rerun)


def test_concurrent_requests_share_one_job_and_a_refused_one_is_not_stored(
    database_url: str,
    tmp_path: Path,
    short_mcap: bytes,
) -> None:
    # One viewer's twenty requests at once: the per-token and viewer caps of the capacity
    # lanes (tests/server/api/test_lanes.py) are raised here, so that the store alone is seen
    lanes = {"heavy_reads_per_token": 32, "viewer_requests_max": 32}
    with _app(database_url, tmp_path, worker_processes=1, worker_queue=1, **lanes) as client:
        first_pass, second_pass = _import(client, short_mcap), _import(client, short_mcap)
        pool, store = _pool(client), _store(client)
        url = f"/api/passes/{first_pass}/recording.mcap"
        held = _hold_the_worker(client, pool)
        started = pool.started
        with ThreadPoolExecutor(max_workers=20) as threads:
            futures = [threads.submit(client.get, url, headers=VIEWER) for _ in range(20)]
            _wait_for(lambda: store.waiting == 20, "twenty requests waiting")
            assert pool.admitted == 2  # the held job, and one computation for the twenty
            held.cancel()  # the held job is killed; the computation gets the worker
            responses = [future.result(timeout=PATIENCE_S) for future in futures]
        assert {r.status_code for r in responses} == {200}
        assert len({(r.content, _tag(r)) for r in responses}) == 1
        assert pool.started == started + 1

        # A full pool refuses the computation: 503 to every request, nothing stored, and
        # the next request after the pool frees up computes it.
        _wait_for(lambda: pool.admitted == 0, "the pool to be free")
        holds = [client.portal.start_task_soon(_hold(pool)) for _ in range(2)]
        _wait_for(lambda: pool.admitted == 2 and pool.running == 1, "a full pool")
        second = f"/api/passes/{second_pass}/recording.mcap"
        with ThreadPoolExecutor(max_workers=5) as threads:
            refused = list(threads.map(lambda _: client.get(second, headers=VIEWER), range(5)))
        for response in refused:
            assert response.status_code == 503, response.text
            assert response.json()["error"]["code"] == "busy"
            assert int(response.headers["retry-after"]) >= 1
        assert [p.parent.name for p in store.stored()] == [first_pass]
        for held in holds:
            held.cancel()
        _wait_for(lambda: pool.admitted == 0, "the pool to be free")
        before = pool.started
        computed = client.get(second, headers=VIEWER)
        assert computed.status_code == 200 and pool.started == before + 1
        assert sorted(p.parent.name for p in store.stored()) == sorted([first_pass, second_pass])


@pytest.mark.parametrize("database_url", ["sqlite"], indirect=True)
def test_the_bytes_kept_stay_within_the_bound_least_recently_served_first(
    database_url: str,
    tmp_path: Path,
    short_mcap: bytes,
) -> None:
    # Room for two recordings of the short pass (each about its imported size), not three.
    bound = len(short_mcap) * 5 // 2
    with _app(database_url, tmp_path, artifact_cache_bytes=bound) as client:
        a, b, c = (_import(client, short_mcap) for _ in range(3))
        pool, store = _pool(client), _store(client)

        def get(pass_id: str) -> None:
            response = client.get(f"/api/passes/{pass_id}/recording.mcap", headers=VIEWER)
            assert response.status_code == 200, response.text
            assert store.stored_bytes <= bound
            on_disk = sum(p.stat().st_size for p in (tmp_path / "artifacts").rglob("*.*"))
            assert on_disk == store.stored_bytes

        def kept() -> list[str]:
            return [p.parent.name for p in store.stored()]

        started = pool.started
        get(a)
        get(b)
        get(a)  # served from its file: now the most recently served
        assert kept() == [b, a] and pool.started == started + 2
        get(c)  # b, the least recently served, makes room
        assert kept() == [a, c] and pool.started == started + 3
        assert not (tmp_path / "artifacts" / b).exists()
        get(b)  # computed again
        assert kept() == [c, b] and pool.started == started + 4


@pytest.mark.parametrize("database_url", ["sqlite"], indirect=True)
def test_a_live_pass_shares_the_computation_in_flight_whatever_its_version(
    database_url: str, tmp_path: Path
) -> None:
    """A running pass changes as frames and events arrive: a request for its recording
    joins the computation in flight instead of starting one per version."""
    with _app(database_url, tmp_path, worker_processes=1, worker_queue=1) as client:
        pass_id = add_pass(client, "live")
        with sessions(client)() as session:
            record = repo.get_pass(session=session, pass_id=pass_id)
            repo.update_pass_state(
                session=session, pass_id=pass_id, expected_version=record.version,
                state="running", updated_at_ns=1, epoch_ns=10**18,
            )  # fmt: skip
            session.commit()
        pool, store = _pool(client), _store(client)
        url = f"/api/passes/{pass_id}/recording.mcap"
        held = _hold_the_worker(client, pool)
        started = pool.started
        with ThreadPoolExecutor(max_workers=2) as threads:
            early = threads.submit(client.get, url, headers=VIEWER)
            _wait_for(lambda: store.waiting == 1, "the first request waiting")
            with sessions(client)() as session:
                repo.add_event(session=session, time_ns=5, kind="note", actor="t", pass_id=pass_id)
                session.commit()
            late = threads.submit(client.get, url, headers=VIEWER)
            _wait_for(lambda: store.waiting == 2, "the second request waiting")
            assert pool.admitted == 2  # the held job and one computation
            held.cancel()
            first, second = early.result(PATIENCE_S), late.result(PATIENCE_S)
        assert first.status_code == second.status_code == 200
        assert (first.content, _tag(first)) == (second.content, _tag(second))
        assert pool.started == started + 1
        # The job read the pass when it ran, after the event: the snapshot is never older
        # than its version. The next request's version counts the event: computed anew.
        assert [e.kind for e in read_mcap(io.BytesIO(first.content)).events] == ["note"]
        now = client.get(url, headers={**VIEWER, "If-None-Match": _tag(first)})
        assert now.status_code == 200 and _tag(now) != _tag(first)
        assert now.content == first.content and pool.started == started + 2
