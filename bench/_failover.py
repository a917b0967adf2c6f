"""What ``bench/bench_failover.py`` is built from: a fresh PostgreSQL schema, two grounds'
environments, a spacecraft that witnesses which ground sent it each command and when, a
health probe, and the archive's checks after a pass (docs/operations.md "One ground in
command").

The witness is the evidence for "sent by two grounds": every command message the
spacecraft's socket reads is logged with the ground it came from (the connection's port)
and the wall clock at reading (loopback: the sending instant, to a millisecond). The
lease's acquisition time is the database's clock, the same host's clock here.
"""

from __future__ import annotations

import asyncio
import json
import os
import subprocess
import sys
import time
import uuid
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sqlalchemy import func, select

from server.storage import repository as repo
from server.storage.db import make_engine, read_session_factory, session_factory
from server.storage.models import GroundLease, TelemetryFrameRecord
from spacecraft.link import LinkConfig
from spacecraft.process import ProcessConfig, SpacecraftProcess

__all__ = [
    "DEFAULT_POSTGRES_URL",
    "OPERATOR",
    "SPACECRAFT_TOKEN",
    "TOKENS",
    "Archive",
    "HealthProbe",
    "Sent",
    "WitnessedSpacecraft",
    "ground_env",
    "percentile",
    "postgres_schema",
    "wait_until",
]

DEFAULT_POSTGRES_URL = "postgresql+psycopg://postgres@127.0.0.1:5432/test"
OPERATOR_TOKEN = "failover-operator-token-012345"
SPACECRAFT_TOKEN = "failover-spacecraft-token-0123"
TOKENS = f"{OPERATOR_TOKEN}=otto:operator,{SPACECRAFT_TOKEN}=ets7:spacecraft"
OPERATOR = {"Authorization": f"Bearer {OPERATOR_TOKEN}"}
#: events read a page at a time (the repository's largest)
EVENTS_PAGE = 10_000
#: the stages of a command the ground has not settled
OPEN_STAGES = ("queued", "released", "sent", "received")


@contextmanager
def postgres_schema(server: str | None = None) -> Iterator[str]:
    """A fresh schema on the PostgreSQL server ``server`` (else ``DATABASE_URL``'s, else the
    local one), as a URL whose connections use it; dropped afterwards."""
    import psycopg
    from sqlalchemy import make_url

    env = server or os.environ.get("DATABASE_URL", "")
    url = make_url(env if env.startswith("postgresql") else DEFAULT_POSTGRES_URL)
    schema = f"failover_{uuid.uuid4().hex[:16]}"
    conninfo = url.set(drivername="postgresql").render_as_string(hide_password=False)
    with psycopg.connect(conninfo, autocommit=True) as conn:
        conn.execute(f"CREATE SCHEMA {schema}")  # hex digits only: ours
        try:
            scoped = url.update_query_dict({"options": f"-csearch_path={schema}"})
            yield scoped.render_as_string(hide_password=False)
        finally:
            conn.execute(f"DROP SCHEMA {schema} CASCADE")


def ground_env(
    name: str,
    data_dir: str,
    lease_ttl_s: float,
    lease_renew_s: float,
    nats: tuple[str, str] | None = None,
) -> dict[str, str]:
    """A ground's environment beside ``DATABASE_URL`` (the flight's uplink defaults); with
    ``nats`` (its URL, the run's stream), its live messages go through JetStream."""
    env = {
        "HIKOBOSHI_TOKENS": TOKENS,
        "HIKOBOSHI_DATA_DIR": data_dir,
        "HIKOBOSHI_GROUND_NAME": name,
        "HIKOBOSHI_LEASE_TTL_S": repr(lease_ttl_s),
        "HIKOBOSHI_LEASE_RENEW_S": repr(lease_renew_s),
    }
    if nats is not None:
        env |= {"HIKOBOSHI_NATS_URL": nats[0], "HIKOBOSHI_NATS_STREAM": nats[1]}
    return env


@dataclass(frozen=True)
class Sent:
    """A command message as the spacecraft's socket read it: from which ground, when."""

    ground: str
    seq: int
    wall_ns: int


class _Witness:
    """The socket as ``SpacecraftProcess._receiver`` iterates it, logging commands."""

    def __init__(self, ws: Any, ground: str, log: list[Sent]) -> None:
        self._ws, self._ground, self._log = ws, ground, log

    def __aiter__(self) -> Any:
        return self._messages()

    async def _messages(self) -> Any:
        async for raw in self._ws:
            body = raw.decode(errors="replace") if isinstance(raw, bytes) else raw
            if '"command"' in body:
                try:
                    doc = json.loads(body)
                except ValueError:
                    doc = None
                if isinstance(doc, dict) and doc.get("type") == "command":
                    self._log.append(Sent(self._ground, int(doc["seq"]), time.time_ns()))
            yield raw


class WitnessedSpacecraft(SpacecraftProcess):
    """The spacecraft process, logging in :attr:`sent` every command it reads and from which
    of ``grounds`` (port -> name) it came."""

    def __init__(self, config: ProcessConfig, grounds: dict[int, str]) -> None:
        super().__init__(config)
        self.grounds = grounds
        self.sent: list[Sent] = []

    async def _receiver(self, ws: Any) -> None:
        ground = self.grounds.get(int(ws.remote_address[1]), "?")
        await super()._receiver(_Witness(ws, ground, self.sent))  # type: ignore[arg-type]

    @classmethod
    def for_grounds(cls, ports: dict[str, int], scale: float, seed: int) -> WitnessedSpacecraft:
        """Given every ground's link URL, in the order of ``ports`` (name -> port)."""
        urls = [f"ws://127.0.0.1:{port}/api/link" for port in ports.values()]
        config = ProcessConfig(
            ground_url=urls[0],
            standby_urls=tuple(urls[1:]),
            token=SPACECRAFT_TOKEN,
            time_scale=scale,
            uplink=LinkConfig(seed=seed * 2 + 1),
            downlink=LinkConfig(seed=seed * 2 + 2),
            seed=seed,
            backoff_initial_s=0.05,
            backoff_max_s=0.3,
            drain_timeout_s=90.0,
        )
        return cls(config, {port: name for name, port in ports.items()})


#: The probe's loop, in a process of its own (stdlib only: it starts in a fraction of a
#: second) so that it times the ground, not this process's event loop, which flies the
#: spacecraft: one line per answer, ``wall_ns latency_s ok``.
_PROBE = """
import http.client, sys, time
host, port, period, path = sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), sys.argv[4]
with open(path, "w", buffering=1) as out:
    conn = None
    while True:
        at, t0 = time.time_ns(), time.monotonic()
        try:
            conn = conn or http.client.HTTPConnection(host, port, timeout=10)
            conn.request("GET", "/api/health")
            response = conn.getresponse()
            response.read()
            ok = response.status == 200
        except (OSError, http.client.HTTPException):
            conn, ok = None, False
        out.write(f"{at} {time.monotonic() - t0:.6f} {int(ok)}\\n")
        time.sleep(period)
"""


class HealthProbe:
    """``GET /api/health`` on one ground every ``period_s`` (wall), from a process of its
    own: each answer's wall time, latency and whether it was a 200."""

    def __init__(self, port: int, path: Path, period_s: float = 0.2) -> None:
        args = ["127.0.0.1", str(port), repr(period_s), str(path)]
        self.path = path
        self.proc = subprocess.Popen([sys.executable, "-c", _PROBE, *args])

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            self.proc.wait(timeout=30)

    def between(self, t0_ns: int, t1_ns: int) -> tuple[list[float], int]:
        """Latencies (s) of the answers sent in ``[t0_ns, t1_ns]``, and how many failed."""
        inside = []
        for line in self.path.read_text().splitlines():
            at, latency, ok = line.split()
            if t0_ns <= int(at) <= t1_ns:
                inside.append((float(latency), ok == "1"))
        return [d for d, _ in inside], sum(1 for _, ok in inside if not ok)


class Archive:
    """The bench's own reads of the run's schema (never a write but the pass it stores)."""

    def __init__(self, database_url: str) -> None:
        self.engine = make_engine(database_url)
        self.sessions = session_factory(self.engine)
        self.readers = read_session_factory(self.engine)

    def close(self) -> None:
        self.engine.dispose()

    def state(self, pass_id: str) -> str:
        with self.readers() as session:
            return str(repo.get_pass(session=session, pass_id=pass_id, refresh=True).state)

    def resolved(self, pass_id: str) -> bool:
        """The pass has ended and no command's stage is still open."""
        with self.readers() as session:
            record = repo.get_pass(session=session, pass_id=pass_id, refresh=True)
            waiting = repo.list_commands(session=session, pass_id=pass_id, stages=OPEN_STAGES)
            return record.state in ("complete", "aborted", "safed") and not waiting

    def events(self, pass_id: str, *kinds: str) -> list[Any]:
        """The pass's events (of ``kinds``, if given), in time order."""
        events: list[Any] = []
        with self.readers() as session:
            while True:
                page = repo.list_events(
                    session=session,
                    pass_id=pass_id,
                    kinds=kinds or None,
                    offset=len(events),
                    limit=EVENTS_PAGE,
                )
                events.extend(page.items)
                if len(page.items) < EVENTS_PAGE:
                    return events

    def lease(self) -> dict[str, Any]:
        with self.readers() as session:
            row = session.scalars(select(GroundLease)).one()
            return {"holder": row.holder, "token": row.token, "acquired_s": row.acquired_s}

    def commands(self, pass_id: str) -> list[Any]:
        with self.readers() as session:
            return list(repo.list_commands(session=session, pass_id=pass_id))

    def frames(self, pass_id: str) -> tuple[list[int], int]:
        """The stored frame numbers of the pass (distinct, ascending) and how many of them
        are stored more than once."""
        frame = TelemetryFrameRecord
        with self.readers() as session:
            key = repo.get_pass(session=session, pass_id=pass_id).id
            seqs = session.scalars(
                select(frame.seq).where(frame.pass_id == key).distinct().order_by(frame.seq)
            ).all()
            twice = session.execute(
                select(func.count()).select_from(
                    select(frame.seq)
                    .where(frame.pass_id == key)
                    .group_by(frame.seq)
                    .having(func.count() > 1)
                    .subquery()
                )
            ).scalar_one()
        return list(seqs), int(twice)

    def window(self, pass_id: str) -> tuple[int, int] | None:
        with self.readers() as session:
            record = repo.get_pass(session=session, pass_id=pass_id, refresh=True)
            if record.telemetry_start_ns is None or record.telemetry_end_ns is None:
                return None
            return int(record.telemetry_start_ns), int(record.telemetry_end_ns)


async def wait_until(
    check: Callable[[], Any], guard_s: float, what: str, period_s: float = 0.2
) -> Any:
    """Poll ``check`` (in a thread) until it returns something true; a guard against a hang,
    not a timing assertion."""
    deadline = time.monotonic() + guard_s
    while not (value := await asyncio.to_thread(check)):
        if time.monotonic() > deadline:
            raise TimeoutError(f"{what}: not within {guard_s:.0f} s")
        await asyncio.sleep(period_s)
    return value


def percentile(values: Sequence[float], q: float) -> float | None:
    """The ``q`` quantile (0..1) of ``values``, linear between ranks; None if empty."""
    xs = sorted(values)
    if not xs:
        return None
    k = (len(xs) - 1) * q
    lo = int(k)
    hi = min(lo + 1, len(xs) - 1)
    return xs[lo] + (xs[hi] - xs[lo]) * (k - lo)
