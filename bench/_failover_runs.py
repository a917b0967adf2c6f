"""One run of a scenario of ``bench/bench_failover.py`` (its docstring says what is measured
and what breaks an invariant): two grounds on a fresh schema, the witnessed spacecraft, the
pass started on ground A, the fault at its moment, and the archive read back against the
vehicle's own record and the frames it generated.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import signal
import subprocess
import tempfile
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
from _common import free_port
from _failover import (
    OPERATOR,
    Archive,
    HealthProbe,
    WitnessedSpacecraft,
    ground_env,
    percentile,
    postgres_schema,
    wait_until,
)

from tests.server.link.harness import add_plan_and_pass, generated_frames, serve_process

__all__ = ["SCENARIOS", "Options", "Run", "fly"]

SCENARIOS = ("kill9-holder", "kill9-abort", "second-serve", "sigterm-holder")
A, B = "ground-a", "ground-b"
ABORT_REASON = "bench: abort right after the takeover"
#: Guards against a hang (wall s), not timing assertions.
START_GUARD_S = 60.0
EXIT_GUARD_S = 120.0
DRAIN_GUARD_S = 150.0
#: after the pass's last tag (wall s at the scale)
RESOLVE_GUARD_S = 120.0


@dataclass(frozen=True)
class Options:
    scale: float
    seed: int
    lease_ttl_s: float
    lease_renew_s: float
    short: bool
    hold_s: float
    out: Path
    #: the PostgreSQL server each run makes its schema on; the NATS server, if any
    server_url: str | None = None
    nats_url: str | None = None


@dataclass
class Run:
    """One run as measured (the bench's docstring defines each figure)."""

    scenario: str
    n: int
    fault_fraction: float
    outcome: str = "-"
    state_reason: str = ""
    sent: int = 0
    by_old: int = 0
    by_new: int = 0
    resent: int = 0
    two_grounds: int = 0
    total: int = 0
    at_tag: int = 0
    expired: int = 0
    rejected: int = 0
    mismatched: int = 0
    frames: int = 0
    lost: int = 0
    twice: int = 0
    #: wall s from the fault to the old holder's exit (as this process saw it)
    old_exit_s: float | None = None
    lease_s: float | None = None
    first_send_s: float | None = None
    resumed_s: float | None = None
    health_p50_s: float | None = None
    health_p99_s: float | None = None
    health_max_s: float | None = None
    health_failed: int = 0
    abort_s: float | None = None
    wall_s: float = 0.0
    #: wall s at each step from the run's start: grounds up, pass started, fault, resolved,
    #: onboard store drained
    phases: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    broken: list[str] = field(default_factory=list)

    @classmethod
    def failed(cls, scenario: str, n: int, fraction: float, why: str) -> Run:
        run = cls(scenario, n, fraction, outcome="error")
        run.broken.append(why)
        return run


async def fly(options: Options, plan: Any, scenario: str, n: int, fraction: float) -> Run:
    """Run ``scenario`` once with the fault at ``fraction`` of ``plan``'s duration."""
    logs = options.out / f"{scenario}-{n:02d}"
    logs.mkdir(parents=True, exist_ok=True)
    with (
        postgres_schema(options.server_url) as url,
        tempfile.TemporaryDirectory(prefix="failover-") as tmp,
        contextlib.closing(Archive(url)) as archive,
        contextlib.ExitStack() as grounds,
    ):
        ports = {A: free_port(), B: free_port()}
        stream = "FAILOVER"  # one for the bench's runs (its server is new each bench)
        nats = (options.nats_url, stream) if options.nats_url is not None else None

        def start(name: str) -> subprocess.Popen[bytes]:
            env = ground_env(
                name,
                str(Path(tmp) / name),
                options.lease_ttl_s,
                options.lease_renew_s,
                nats,
            )
            log = logs / f"{name}.log"
            return grounds.enter_context(serve_process(url, ports[name], log, env))

        # the spacecraft's log (a link down at every try during a takeover) to the run's
        handler = logging.FileHandler(logs / "spacecraft.log")
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(message)s"))
        spacecraft_log = logging.getLogger("hikoboshi.spacecraft")
        spacecraft_log.addHandler(handler)
        spacecraft_log.propagate = False
        try:
            flight = _Flight(options, plan, scenario, n, fraction, archive, ports, logs)
            return await flight.run(start)
        finally:
            spacecraft_log.removeHandler(handler)
            handler.close()


class _Flight:
    """The run's state, from the grounds' start to the archive's checks."""

    def __init__(
        self,
        options: Options,
        plan: Any,
        scenario: str,
        n: int,
        fraction: float,
        archive: Archive,
        ports: dict[str, int],
        logs: Path,
    ) -> None:
        self.options, self.plan, self.scenario = options, plan, scenario
        self.archive, self.ports, self.logs = archive, ports, logs
        self.base = {name: f"http://127.0.0.1:{port}" for name, port in ports.items()}
        self.result = Run(scenario, n, fraction)
        self.name = f"failover {scenario} {n}"
        self.craft = WitnessedSpacecraft.for_grounds(ports, options.scale, options.seed + n)
        self.generated = generated_frames(self.craft)
        self.fault_ns = 0
        self.health_until_ns = 0

    async def run(self, start: Any) -> Run:
        r, archive = self.result, self.archive
        t0 = time.monotonic()

        def phase(name: str) -> None:
            r.phases[name] = round(time.monotonic() - t0, 1)

        ground_a = await asyncio.to_thread(start, A)
        second = self.scenario == "second-serve"
        if not second:
            await asyncio.to_thread(start, B)
        # the contact window as the demo schedules it (real time: its flight rule
        # ``fits_pass``); the accelerated pass ends well inside it
        window_s = self.plan.duration_s + 120.0
        pass_id = await asyncio.to_thread(
            add_plan_and_pass,
            archive.sessions,
            self.plan,
            self.name,
            now_ns=time.time_ns(),
            window_s=window_s,
        )
        stop = asyncio.Event()
        task = asyncio.create_task(self.craft.run(stop))
        probe = HealthProbe(self.ports[A if second else B], self.logs / "health.txt")
        phase("grounds")
        try:
            async with httpx.AsyncClient(timeout=60.0, headers=OPERATOR) as api:
                await wait_until(lambda: self.craft.connections > 0, START_GUARD_S, "a link")
                holder = (await api.get(f"{self.base[A]}/api/health")).json().get("command")
                if holder != "holder":
                    raise RuntimeError(f"ground A started as {holder!r}, not the holder")
                started = await api.post(
                    f"{self.base[A]}/api/passes/{pass_id}/start",
                    json={"confirm": f"START {self.name}"},
                )
                if started.status_code != 200:
                    raise RuntimeError(f"the start answered {started.status_code}: {started.text}")
                epoch_ns = int(started.json()["epoch_ns"])
                phase("started")
                fault_at_ns = epoch_ns + round(r.fault_fraction * self.plan.duration_s * 1e9)
                while self.craft.onboard_ns(self.craft.onboard_s()) < fault_at_ns:
                    await asyncio.sleep(0.01)
                self.fault_ns = time.time_ns()
                phase("fault")
                if second:
                    await self._second_serve(api, start, pass_id)
                else:
                    how = signal.SIGTERM if self.scenario == "sigterm-holder" else signal.SIGKILL
                    ground_a.send_signal(how)
                    await asyncio.to_thread(ground_a.wait, EXIT_GUARD_S)
                    r.old_exit_s = (time.time_ns() - self.fault_ns) / 1e9
                    if self.scenario == "kill9-abort":
                        await self._abort(api, pass_id)
                guard_s = self.plan.duration_s / self.options.scale + RESOLVE_GUARD_S
                try:
                    await wait_until(lambda: archive.resolved(pass_id), guard_s, "resolved")
                except TimeoutError:  # checked as it stands: its open stages count as lost
                    state = await asyncio.to_thread(archive.state, pass_id)
                    r.broken.append(f"the pass not resolved {guard_s:.0f} s on: still {state}")
                phase("resolved")
                stays = self.base[A if second else B]
                summary = await api.get(f"{stays}/api/passes/{pass_id}/summary")
                if summary.status_code != 200:
                    raise RuntimeError(f"the summary answered {summary.status_code}")
                stop.set()
                await asyncio.wait_for(task, DRAIN_GUARD_S)  # the onboard store drained
                phase("drained")
        finally:
            stop.set()
            probe.stop()
            with contextlib.suppress(Exception):
                await asyncio.wait_for(task, DRAIN_GUARD_S)
        await asyncio.to_thread(self._check, pass_id, summary.json())
        self._health(probe)
        return r

    async def _second_serve(self, api: httpx.AsyncClient, start: Any, pass_id: str) -> None:
        """Ground B started by mistake, asked, left up, stopped; nothing of it on the pass."""
        r = self.result
        mistaken = await asyncio.to_thread(start, B)
        b = self.base[B]
        health = (await api.get(f"{b}/api/health")).json()
        probe = await api.get(f"{b}/api/command")
        refused = await api.post(
            f"{b}/api/passes/{pass_id}/start", json={"confirm": f"START {self.name}"}
        )
        if health.get("command") != "standby":
            r.broken.append(f"B's health says {health}, not a standby")
        if probe.status_code != 503:
            r.broken.append(f"B's /api/command answered {probe.status_code}, not 503")
        code = refused.json().get("error", {}).get("code")
        if refused.status_code != 409 or code != "standby":
            r.broken.append(f"a start on B answered {refused.status_code} {code}, not 409 standby")
        await asyncio.sleep(self.options.hold_s)
        state = await asyncio.to_thread(self.archive.state, pass_id)
        mistaken.send_signal(signal.SIGTERM)
        await asyncio.to_thread(mistaken.wait, EXIT_GUARD_S)
        self.health_until_ns = time.time_ns()
        up_s = (self.health_until_ns - self.fault_ns) / 1e9
        r.notes.append(
            f"B up {up_s:.1f} s from its start to its exit; the pass {state} at its stop"
        )
        if mistaken.returncode not in (0, -signal.SIGTERM):
            r.notes.append(f"B exited with {mistaken.returncode}")

    async def _abort(self, api: httpx.AsyncClient, pass_id: str) -> None:
        """The operator's abort on B once B has resumed the pass; its answer timed."""
        r = self.result
        await wait_until(
            lambda: self.archive.events(pass_id, "pass_resumed"), EXIT_GUARD_S, "pass_resumed"
        )
        t0 = time.monotonic()
        answer = await api.post(
            f"{self.base[B]}/api/passes/{pass_id}/abort",
            json={"confirm": f"ABORT {self.name}", "reason": ABORT_REASON},
        )
        r.abort_s = time.monotonic() - t0
        if answer.status_code != 200:
            r.broken.append(f"the abort on B answered {answer.status_code}: {answer.text[:200]}")

    def _check(self, pass_id: str, summary: dict[str, Any]) -> None:
        """The run's figures from the archive, the witness and the vehicle; what broke."""
        r, archive = self.result, self.archive
        state, r.state_reason = summary["state"], summary.get("state_reason") or ""
        r.outcome = summary["outcome"] if state == "complete" else state
        r.total, r.at_tag = summary["commands_total"], summary["commands_executed_at_tag"]
        r.expired = summary["commands_expired"]
        r.rejected = sum(summary["commands_rejected"].values())
        differ: Counter[tuple[str, str | None]] = Counter()
        for c in archive.commands(pass_id):
            ack = self.craft.vehicle.outcome(c.seq)
            vehicle = None if ack is None else ack.stage.value
            if ack is not None and ack.reason is not None and ack.reason.value == "cancelled":
                vehicle = "cancelled"  # deleted by the abort's schedule_delete
            if (vehicle is None and c.stage not in ("expired", "cancelled")) or (
                vehicle is not None and vehicle != c.stage
            ):
                differ[(c.stage, vehicle)] += 1
        r.mismatched = sum(differ.values())
        if differ:
            pairs = ", ".join(f"{n} {a} (vehicle: {v})" for (a, v), n in differ.most_common())
            r.notes.append(f"stages against the vehicle's record: {pairs}")
        aborting = self.scenario == "kill9-abort"
        if aborting and (state != "aborted" or ABORT_REASON not in r.state_reason):
            r.broken.append(f"the pass ended {state} ({r.state_reason}), not as the abort asked")
        if not aborting and state != "complete":
            r.broken.append(f"the pass ended {state}: {r.state_reason}")
        if r.mismatched:
            r.broken.append(f"{r.mismatched} commands' stages differ from the vehicle's record")
        self._frames(pass_id)
        self._senders(pass_id)

    def _frames(self, pass_id: str) -> None:
        r = self.result
        window = self.archive.window(pass_id)
        if window is None:
            r.broken.append("the pass has no telemetry window")
            return
        expected = {f.seq for f in self.generated if window[0] <= f.generation_time_ns < window[1]}
        stored, r.twice = self.archive.frames(pass_id)
        r.frames, r.lost = len(expected), len(expected - set(stored))
        extra = len(set(stored) - expected)
        if r.lost or r.twice or extra:
            r.broken.append(
                f"frames: {r.lost} of {r.frames} lost, {r.twice} stored twice,"
                f" {extra} stored that the window did not generate"
            )

    def _senders(self, pass_id: str) -> None:
        """Who sent what, and when, against the lease's acquisition and the events."""
        r = self.result
        old = [s for s in self.craft.sent if s.ground == A]
        new = [s for s in self.craft.sent if s.ground == B]
        old_seqs, new_seqs = {s.seq for s in old}, {s.seq for s in new}
        r.sent, r.by_old, r.by_new = len(old_seqs | new_seqs), len(old_seqs), len(new_seqs)
        r.resent = len(old_seqs & new_seqs)
        lease = self.archive.lease()
        kinds = Counter(e.kind for e in self.archive.events(pass_id))
        written = {k: kinds[k] for k in ("pass_resumed", "ground_stopped") if kinds[k]}
        if self.scenario == "second-serve":
            r.two_grounds = len(new_seqs)
            if lease["token"] != 1 or not lease["holder"].startswith(f"{A}:"):
                r.broken.append(f"the lease moved while A lived: {lease}")
            if written:
                r.broken.append(f"events written on A's pass by another ground: {written}")
            if r.two_grounds:
                r.broken.append(f"B, a standby, sent {r.two_grounds} commands")
            return
        if lease["token"] != 2 or not lease["holder"].startswith(f"{B}:"):
            r.broken.append(f"the lease ended {lease}: not B's second token")
        acquired_ns = round(lease["acquired_s"] * 1e9)
        first_ns = min((s.wall_ns for s in new), default=None)
        since_ns = acquired_ns if first_ns is None else min(acquired_ns, first_ns)
        r.two_grounds = len({s.seq for s in old if s.wall_ns >= since_ns})
        if r.two_grounds:
            r.broken.append(f"{r.two_grounds} commands sent by A after B took command")
        r.lease_s = (acquired_ns - self.fault_ns) / 1e9
        if first_ns is not None:
            r.first_send_s = (first_ns - self.fault_ns) / 1e9
        resumed = self.archive.events(pass_id, "pass_resumed")
        stopped = kinds["ground_stopped"]
        if len(resumed) != 1:
            r.broken.append(f"{len(resumed)} pass_resumed events, not one")
        else:
            r.resumed_s = (resumed[0].time_ns - self.fault_ns) / 1e9
        if stopped != (self.scenario == "sigterm-holder"):
            r.broken.append(f"{stopped} ground_stopped events")
        ends = [t for t in (r.first_send_s, r.resumed_s, r.lease_s) if t is not None]
        self.health_until_ns = self.fault_ns + round((max(ends, default=0.0) + 1.0) * 1e9)

    def _health(self, probe: HealthProbe) -> None:
        r = self.result
        latencies, r.health_failed = probe.between(self.fault_ns, self.health_until_ns)
        r.health_p50_s, r.health_p99_s = percentile(latencies, 0.5), percentile(latencies, 0.99)
        r.health_max_s = max(latencies, default=None)
