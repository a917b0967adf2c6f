"""The main job: the ground service, the simulated spacecraft and a whole ETS-VII pass
(or, with ``--robot FILE``, the whole pass of that robot description).

1. The ground service starts on embedded SQLite under ``OUT`` (uvicorn, loopback), with
   fresh API tokens for an operator, a viewer and the spacecraft.
2. The pass plan (all four experiments, ``planner.schedule.plan_pass``) is made through the
   REST API, and a pass is scheduled with it.
3. The simulated spacecraft starts as its own process (``hikoboshi spacecraft``) behind the
   emulated relay (3 s each way, ``--loss``, ``--outage``), at ``--speed`` times real time.
4. The operator's start (with its confirmation) goes through the API; the ground streams
   the 4 Hz commands and archives the telemetry; the job follows the pass until it ends.
5. The spacecraft is stopped (it drains its telemetry store), and the pass summary
   (``GET /api/passes/{id}/summary``) is printed and written to ``OUT/summary.json``.
6. The post-pass analyses run on the server; the report (``report.html``, ``report.json``)
   and the MCAP recording (``pass.mcap``) are written to ``OUT``.

Faults (``--fault SPEC``, repeatable, :mod:`spacecraft.faults`'s grammar) go to the
spacecraft process as they are; it always writes its truth log to ``OUT/truth.jsonl``. The
summary adds what the pass's limits and the vehicle's own protection did:

- ``alarms``: every alarm of the pass (``GET /api/alarms?pass=``), each with its bands'
  crossings from its timeline, and how many went above ``watch``;
- ``safing``: the vehicle's safing as the ground heard it (the link status's last ``safing``
  report, the pass's ``vehicle_safed`` event and its state), the truth log's faults and
  safing entries, and the pass's commands executed on board after the vehicle safed (the
  vehicle's rule makes it 0);
- ``verdict``: the exit status's reasons (:func:`verdict`).

Onboard times are also given as seconds since the spacecraft's start (the truth log's
``start``, the origin of ``--fault`` and ``--outage`` times), and the ground's own times
on the onboard clock through the link's clock mapping, sampled while the pass ran.

With a robot description the ground is given the file (``Settings.robot_files``, as
``hikoboshi serve --robot``), the plan request names the robot, and the spacecraft flies
the same file (``hikoboshi spacecraft --robot``): the ground checks that the vehicle's
``hello`` names the robot the plan was made for before it starts the pass.

Only public interfaces are used: REST, the link websocket, process signals.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import secrets
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

from planner.limits import SEVERITY_RANK, Severity
from server.settings import ApiToken, Role, Settings
from server.storage.db import sqlite_url

__all__ = [
    "DemoError",
    "DemoOptions",
    "OnboardClock",
    "alarms_section",
    "check_fault_specs",
    "expected_epoch_s",
    "read_truth_log",
    "run_demo",
    "safing_section",
    "segments_section",
    "spacecraft_command",
    "verdict",
]

#: Progress callback: (phase, done, total).
Progress = Callable[[str, float, float], None]


class DemoError(RuntimeError):
    """The demo could not run to the end; the message says where it stopped."""


@dataclass(frozen=True)
class DemoOptions:
    out: Path = Path("out/demo")
    speed: float = 20.0
    loss: float = 0.0
    #: LOS windows "START:END", onboard s from the spacecraft's start.
    outages: tuple[str, ...] = ()
    port: int = 8000
    seed: int = 0
    #: A subset of the schedule's experiments (all four by default).
    experiments: tuple[str, ...] = ()
    timeout_s: float = 900.0
    #: Keep the ground service up after the pass (console, reports) until Ctrl-C.
    serve_after: bool = False
    #: Called once the service is up: (console URL, the file holding its tokens). Never
    #: the tokens: what is printed ends up in logs.
    on_ready: Callable[[str, Path], None] | None = None
    extra_spacecraft_args: tuple[str, ...] = field(default=())
    #: A robot description (TOML) to fly instead of the built-in ETS-VII.
    robot: Path | None = None
    #: Faults for the spacecraft (``--fault`` specs, spacecraft/faults.py's grammar).
    faults: tuple[str, ...] = ()
    #: The logs' format and least level (server/logs.py): the ground's in OUT/ground.log,
    #: the spacecraft's in OUT/spacecraft.log.
    log_format: str = "text"
    log_level: str = "info"
    #: Stream the pass to Foxglove on this port (the ground's ``foxglove_port``); None: no.
    foxglove_port: int | None = None


class _Api:
    """A small JSON client for the ground's REST API (the standard library's urllib)."""

    def __init__(self, base: str, token: str) -> None:
        self.base = base
        self._token = token

    def call(self, method: str, path: str, body: Any = None, timeout_s: float = 120.0) -> Any:
        return json.loads(self.raw(method, path, body, timeout_s))

    def raw(self, method: str, path: str, body: Any = None, timeout_s: float = 120.0) -> bytes:
        data = None if body is None else json.dumps(body).encode()
        request = urllib.request.Request(
            self.base + path,
            data=data,
            method=method,
            headers={"Authorization": f"Bearer {self._token}", "Content-Type": "application/json"},
        )
        try:
            with urllib.request.urlopen(request, timeout=timeout_s) as response:
                body_out: bytes = response.read()
                return body_out
        except urllib.error.HTTPError as exc:
            raise DemoError(f"{method} {path}: {exc.code} {exc.read().decode()[:500]}") from None
        except (TimeoutError, urllib.error.URLError) as exc:
            # a ground that does not answer (overloaded, or gone): a reason, not a traceback
            reason = getattr(exc, "reason", exc)  # URLError's reason, or the timeout itself
            raise DemoError(
                f"{method} {path}: no answer from the ground service within {timeout_s:g} s"
                f" ({reason}); its log is ground.log in the output folder"
            ) from None


def _port(preferred: int) -> int:
    """``preferred`` if it is free on loopback, else any free port."""
    for candidate in (preferred, 0):
        with socket.socket() as sock:
            try:
                sock.bind(("127.0.0.1", candidate))
            except OSError:
                continue
            return int(sock.getsockname()[1])
    raise DemoError("no free port on 127.0.0.1")


@contextmanager
def _ground(settings: Settings, port: int) -> Iterator[None]:
    # The application and uvicorn are imported here, not with the module (1.5 of its 2 s of
    # imports, measured): hikoboshi demo checks its options with this module first.
    import uvicorn

    from server.api.edge import uvicorn_config
    from server.app import create_app

    # As `hikoboshi serve` runs it: forwarded headers believed from no one, logs redacted.
    config = uvicorn_config(
        create_app(settings), settings, host="127.0.0.1", port=port, log_level="warning"
    )
    server = uvicorn.Server(config)
    thread = threading.Thread(target=server.run, name="ground", daemon=True)
    thread.start()
    deadline = time.monotonic() + 60.0
    while not server.started:
        if not thread.is_alive() or time.monotonic() > deadline:
            raise DemoError(f"the ground service did not start on port {port}")
        time.sleep(0.02)
    try:
        yield
    finally:
        server.should_exit = True
        thread.join(timeout=60.0)


def spacecraft_command(
    port: int, *, speed: float, loss: float, seed: int, log_format: str, log_level: str
) -> list[str]:
    """``hikoboshi spacecraft``'s command line for a demo's vehicle on ``port``, before its
    demo's own options (its token goes in its environment, never here)."""
    return [
        sys.executable,
        "-m",
        "hikoboshi",
        "spacecraft",
        "--ground",
        f"ws://127.0.0.1:{port}/api/link",
        "--log-format",
        log_format,
        "--log-level",
        log_level,
        "--time-scale",
        repr(speed),
        "--loss",
        repr(loss),
        "--seed",
        str(seed),
    ]


@contextmanager
def _spacecraft(
    args: list[str], log_path: Path, env: dict[str, str]
) -> Iterator[subprocess.Popen[bytes]]:
    with log_path.open("wb") as log:
        proc = subprocess.Popen(
            args, stdout=log, stderr=subprocess.STDOUT, env={**os.environ, **env}
        )
    try:
        yield proc
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout=120.0)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def _tokens(out: Path) -> dict[str, ApiToken]:
    tokens = {
        secrets.token_urlsafe(18): ApiToken(name="demo-operator", role=Role.OPERATOR),
        secrets.token_urlsafe(18): ApiToken(name="demo-viewer", role=Role.VIEWER),
        secrets.token_urlsafe(18): ApiToken(name="ets-vii", role=Role.SPACECRAFT),
    }
    # For `hikoboshi serve` on the same data afterwards (HIKOBOSHI_TOKENS=...).
    line = ",".join(f"{t}={a.name}:{a.role.value}" for t, a in tokens.items())
    path = out / "tokens"
    path.write_text(line + "\n")
    os.chmod(path, 0o600)
    return tokens


def _token_of(tokens: dict[str, ApiToken], role: Role) -> str:
    return next(t for t, a in tokens.items() if a.role is role)


def run_demo(options: DemoOptions, progress: Progress | None = None) -> dict[str, Any]:
    """Run the whole demo pass; the summary (also in ``OUT/summary.json``)."""
    report = progress or (lambda phase, done, total: None)
    out = options.out
    # a fault the spacecraft would refuse stops the demo before anything starts
    check_fault_specs(options.faults, options.robot)
    out.mkdir(parents=True, exist_ok=True)
    truth_log = out / "truth.jsonl"
    tokens = _tokens(out)
    operator = _token_of(tokens, Role.OPERATOR)
    port = _port(options.port)
    base = f"http://127.0.0.1:{port}"
    # The flight's uplink settings at any speed: a command goes up once its tag is within
    # 120 s of the onboard clock and is sent again until acknowledged, so the ground's own
    # pauses delay none.
    robot = None if options.robot is None else options.robot.resolve()
    robot_name, robot_label = None, "ETS-VII"
    if robot is not None:
        from planner.description import load_robot
        from planner.errors import PlannerError

        try:
            robot_name = robot_label = load_robot(robot).name
        except PlannerError as exc:
            raise DemoError(str(exc)) from None
    settings = Settings(
        data_dir=out,
        tokens=tokens,
        robot_files=() if robot is None else (robot,),
        foxglove_port=options.foxglove_port,
    )
    started = time.monotonic()
    with _ground(settings, port):
        api = _Api(base, operator)
        if options.on_ready is not None:
            options.on_ready(f"{base}/", out / "tokens")
        report("planning the pass (all four experiments)", 0, 1)
        parameters = {"experiments": list(options.experiments)} if options.experiments else {}
        request: dict[str, Any] = {"experiment": "pass", "parameters": parameters}
        if robot_name is not None:
            request["robot"] = robot_name
        # planning the whole pass is seconds of CPU on a quiet machine and minutes on a
        # crowded one: it may take the demo's whole timeout
        plan = api.call("POST", "/api/plans", request, timeout_s=options.timeout_s)
        report("planning the pass (all four experiments)", 1, 1)
        rules = plan.get("flight_rules") or {}
        if not rules.get("passed", False):
            failing = [
                f"{r['rule']} {r['value']:.4g} {r['unit']} (limit {r['limit']:.4g})"
                for r in rules.get("rows", [])
                if r["verdict"] == "fail"
            ]
            raise DemoError(
                f"plan {plan['id']} fails the flight rules and would not be uplinked: "
                + ("; ".join(failing) or "it could not be checked")
            )
        duration_s = float(plan["duration_s"])
        name = f"{robot_label} demo {datetime.now(UTC):%Y-%m-%d %H:%M:%S}"
        now = datetime.now(UTC)
        # The contact window as flight would schedule it (real time): the accelerated pass
        # ends well inside it.
        window_s = duration_s + 120.0
        record = api.call(
            "POST",
            "/api/passes",
            {
                "plan_id": plan["id"],
                "name": name,
                "aos_time": now.isoformat(),
                "los_time": (now + timedelta(seconds=window_s)).isoformat(),
                "relay": "TDRS (emulated)",
            },
        )
        pass_id = record["id"]
        args = [
            *spacecraft_command(
                port,
                speed=options.speed,
                loss=options.loss,
                seed=options.seed,
                log_format=options.log_format,
                log_level=options.log_level,
            ),
            *(a for o in options.outages for a in ("--outage", o)),
            *(() if robot is None else ("--robot", str(robot))),
            *(a for f in options.faults for a in ("--fault", f)),
            "--truth-log",
            str(truth_log.resolve()),
            *options.extra_spacecraft_args,
        ]
        sampler = _ClockSampler()
        # Its token in its environment, not on its command line (where ps shows it).
        token_env = {"HIKOBOSHI_SPACECRAFT_TOKEN": _token_of(tokens, Role.SPACECRAFT)}
        with _spacecraft(args, out / "spacecraft.log", token_env) as proc:
            _wait_connected(api, proc)
            started_pass = api.call(
                "POST", f"/api/passes/{pass_id}/start", {"confirm": f"START {name}"}
            )
            epoch_ns = int(started_pass["epoch_ns"])
            state = _follow(api, proc, pass_id, epoch_ns, duration_s, options, report, sampler)
            _settle(api, pass_id, options.speed)
            # the vehicle's mode as the pass left it (the spacecraft is still connected)
            link_end = api.call("GET", "/api/link/status")
            report("draining the onboard telemetry store", 0, 1)
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout=120.0)
            except subprocess.TimeoutExpired:
                raise DemoError("the spacecraft did not drain its telemetry in 120 s") from None
            report("draining the onboard telemetry store", 1, 1)
        summary = api.call("GET", f"/api/passes/{pass_id}/summary")
        link = api.call("GET", "/api/link/status")
        truth = read_truth_log(truth_log)
        clock = sampler.clock(_truth_start_ns(truth))
        sections = _limits_and_safing(api, pass_id, link_end, truth, clock)
        report("post-pass analyses, report and recording", 0, 3)
        analyses = api.call("POST", f"/api/passes/{pass_id}/analyses", timeout_s=600.0)
        failed = [a["kind"] for a in analyses["data"] if a["status"] != "ok"]
        report("post-pass analyses, report and recording", 1, 3)
        (out / "report.html").write_bytes(api.raw("GET", f"/api/passes/{pass_id}/report.html"))
        (out / "report.json").write_bytes(api.raw("GET", f"/api/passes/{pass_id}/report"))
        report("post-pass analyses, report and recording", 2, 3)
        (out / "pass.mcap").write_bytes(
            api.raw("GET", f"/api/passes/{pass_id}/recording.mcap", timeout_s=600.0)
        )
        report("post-pass analyses, report and recording", 3, 3)
        if options.serve_after:
            report(f"serving {base}/ until Ctrl-C", 0, 1)
            with contextlib.suppress(KeyboardInterrupt):
                while True:
                    time.sleep(1.0)
    result = {
        **summary,
        "final_state": state,
        "robot": robot_name or "ets7",
        "vehicle_robot": link.get("robot"),
        "plan_duration_s": duration_s,
        "speed": options.speed,
        "loss": options.loss,
        "outages": list(options.outages),
        "faults": list(options.faults),
        "epoch_onboard_s": clock.since_start_s(epoch_ns),
        "segments": segments_section(plan.get("segments", []), epoch_ns, clock),
        **sections,
        "truth_log": str(truth_log.resolve()),
        "wall_time_s": round(time.monotonic() - started, 1),
        "round_trip_s": link.get("round_trip_s"),
        "retransmit_requests": link.get("retransmit_requests"),
        "database": str((out / "hikoboshi.sqlite3").resolve()),
        "database_url": sqlite_url(out),
        "spacecraft_log": str((out / "spacecraft.log").resolve()),
        "serve_again": (
            f"HIKOBOSHI_DATA_DIR={out} HIKOBOSHI_TOKENS=$(cat {out}/tokens) "
            f"hikoboshi serve --port {port}"
        ),
        "analyses_failed": failed,
        "report_html": str((out / "report.html").resolve()),
        "report_json": str((out / "report.json").resolve()),
        "recording_mcap": str((out / "pass.mcap").resolve()),
        "console_url": f"{base}/",
        "tokens_file": str((out / "tokens").resolve()),
        "api_docs_url": f"{base}/docs",
        "pass_url": f"{base}/api/passes/{pass_id}",
        "summary_url": f"{base}/api/passes/{pass_id}/summary",
    }
    result["verdict"] = verdict(result)
    (out / "summary.json").write_text(json.dumps(result, indent=2) + "\n")
    return result


def _limits_and_safing(
    api: _Api, pass_id: str, link: dict[str, Any], truth: list[dict[str, Any]], clock: OnboardClock
) -> dict[str, Any]:
    """The summary's ``alarms`` and ``safing`` sections, from the ground's REST routes."""
    alarms = _all(api, f"/api/alarms?pass={pass_id}", "alarms")
    record = api.call("GET", f"/api/passes/{pass_id}")
    events: list[dict[str, Any]] = []
    executed: list[dict[str, Any]] = []
    cancelled: list[dict[str, Any]] = []
    if link.get("safing") is not None or record["state"] == "safed":
        # the audit log of a pass holds an event per command stage: read only when it tells
        events = _all(api, f"/api/events?pass_id={pass_id}", "data")
        executed = _all(api, f"/api/passes/{pass_id}/commands?stage=executed", "data")
        cancelled = _all(api, f"/api/passes/{pass_id}/commands?stage=cancelled", "data")
    return {
        "alarms": alarms_section(alarms, clock),
        "safing": safing_section(
            record=record,
            link=link,
            alarms=alarms,
            events=events,
            truth=truth,
            executed=executed,
            cancelled=cancelled,
            clock=clock,
        ),
    }


def _all(api: _Api, path: str, key: str, page: int = 1000) -> list[dict[str, Any]]:
    """Every item of a paged listing (``offset``/``limit``, ``count`` the total)."""
    items: list[dict[str, Any]] = []
    sep = "&" if "?" in path else "?"
    while True:
        body = api.call("GET", f"{path}{sep}offset={len(items)}&limit={page}")
        batch = body[key]
        items.extend(batch)
        if not batch or len(items) >= int(body["count"]):
            return items


def _wait_connected(api: _Api, proc: subprocess.Popen[bytes]) -> None:
    deadline = time.monotonic() + 60.0
    while not api.call("GET", "/api/link/status")["connected"]:
        if proc.poll() is not None:
            raise DemoError(f"the spacecraft process exited with {proc.returncode}")
        if time.monotonic() > deadline:
            raise DemoError("the spacecraft did not connect within 60 s")
        time.sleep(0.1)


def _settle(api: _Api, pass_id: str, speed: float, timeout_s: float = 60.0) -> None:
    """Before the spacecraft stops: let the onboard clock pass the end of the pass's
    telemetry window (every frame of it generated; the drain delivers them: a safed pass's
    runs on a minute onboard past the safing) and the ground resolve the commands still in
    flight (an abort or a safing leaves some). ``timeout_s`` wall s beyond the window's
    rest at ``speed``."""
    deadline: float | None = None
    while deadline is None or time.monotonic() < deadline:
        summary = api.call("GET", f"/api/passes/{pass_id}/summary")
        onboard = api.call("GET", "/api/link/status").get("onboard_time_ns")
        end = summary["telemetry_end_ns"]
        if deadline is None:
            rest_s = 0.0 if end is None or onboard is None else max(0, end - onboard) / 1e9
            deadline = time.monotonic() + timeout_s + rest_s / speed
        if (
            end is not None
            and onboard is not None
            and onboard >= end
            and summary["commands_outstanding"] == 0
        ):
            return
        time.sleep(0.25)


def _follow(
    api: _Api,
    proc: subprocess.Popen[bytes],
    pass_id: str,
    epoch_ns: int,
    duration_s: float,
    options: DemoOptions,
    report: Progress,
    sampler: _ClockSampler,
) -> str:
    """Poll the pass until it ends (``complete``, ``aborted`` or ``safed``); its final
    state. Each link status read is a sample of the ground's onboard clock mapping."""
    deadline = time.monotonic() + options.timeout_s
    while True:
        record = api.call("GET", f"/api/passes/{pass_id}")
        if record["state"] in TERMINAL_STATES:
            report("pass", duration_s, duration_s)
            return str(record["state"])
        if proc.poll() is not None:
            raise DemoError(f"the spacecraft process exited with {proc.returncode} mid-pass")
        if time.monotonic() > deadline:
            raise DemoError(f"the pass did not end within {options.timeout_s:.0f} s")
        before_ns = time.time_ns()
        status = api.call("GET", "/api/link/status")
        after_ns = time.time_ns()
        onboard = status.get("onboard_time_ns")
        sampler.offer(before_ns, after_ns, onboard, status.get("time_scale"))
        if onboard is not None:
            t_s = min(duration_s, max(0.0, (onboard - epoch_ns) / 1e9))
            report("pass", t_s, duration_s)
        time.sleep(0.25)


# -- the summary's sections (pure: the documents the routes served in, JSON out) -----------

#: The states a pass ends in (``safed``: the vehicle safed itself; the ground stopped it).
TERMINAL_STATES = ("complete", "aborted", "safed")
#: The audit events that tell the vehicle's safing and the pass's end.
_SAFING_EVENTS = (
    "vehicle_safed",
    "vehicle_safe_exit_requested",
    "vehicle_safe_exited",
    "vehicle_safe_exit_unverified",
)
#: Wall s from the spacecraft's start to the demo's start request (the process connects
#: and says hello; the demo polls the link every 0.1 s): 0.19 measured at 20x on a loaded
#: 2-core machine (the plan's t = 0 came at 76.75 s).
CONNECT_WALL_S = 0.2


@dataclass(frozen=True)
class OnboardClock:
    """Onboard times as seconds since the spacecraft's start (``start_ns``: the truth log's
    ``start``; None when it could not be read), and ground times on the onboard clock: the
    link's mapping read ``onboard_ns`` at the ground instant ``ground_ns`` and runs at
    ``scale`` (``uncertainty_s``: onboard s, half the wall time the read took, scaled)."""

    start_ns: int | None = None
    ground_ns: int | None = None
    onboard_ns: int | None = None
    scale: float | None = None
    uncertainty_s: float | None = None

    def since_start_s(self, onboard_ns: int | None) -> float | None:
        """Onboard s since the spacecraft's start (ms), or None where the demo cannot say."""
        if onboard_ns is None or self.start_ns is None:
            return None
        return round((onboard_ns - self.start_ns) / 1e9, 3)

    def ground_s(self, ground_ns: int | None) -> float | None:
        """A ground (wall clock) instant as onboard s since the spacecraft's start."""
        if ground_ns is None or self.ground_ns is None or self.onboard_ns is None:
            return None
        if self.scale is None:
            return None
        return self.since_start_s(
            self.onboard_ns + round((ground_ns - self.ground_ns) * self.scale)
        )


class _ClockSampler:
    """The narrowest read of the ground's onboard clock mapping (``GET /api/link/status``
    between two readings of the wall clock: the ground's ``SystemClock`` reads the same
    ``time.time_ns`` in this process); the latest of equally narrow ones."""

    def __init__(self) -> None:
        self._best: tuple[int, int, int, float] | None = None  # width, mid, onboard, scale

    def offer(self, before_ns: int, after_ns: int, onboard_ns: Any, scale: Any) -> None:
        if onboard_ns is None or not scale:
            return
        width = after_ns - before_ns
        if self._best is None or width <= self._best[0]:
            self._best = (width, (before_ns + after_ns) // 2, int(onboard_ns), float(scale))

    def clock(self, start_ns: int | None) -> OnboardClock:
        if self._best is None:
            return OnboardClock(start_ns=start_ns)
        width, mid, onboard, scale = self._best
        return OnboardClock(start_ns, mid, onboard, scale, round(width / 2e9 * scale, 3))


def check_fault_specs(specs: Sequence[str], robot: Path | None) -> None:
    """Refuse, before anything starts, a fault the spacecraft process would refuse: one it
    cannot read, or one naming a joint or wheel the robot (``robot``'s description, or
    ETS-VII) lacks. :class:`DemoError` with spacecraft/faults.py's one-line reason."""
    if not specs:
        return
    from planner.errors import PlannerError
    from spacecraft.faults import FaultSpecError, check_faults, parse_fault

    try:
        faults = [parse_fault(spec) for spec in specs]
        if robot is None:
            from planner.model import default_model

            model = default_model()
        else:
            from planner.description import load_robot

            model = load_robot(robot).model
        check_faults(faults, n_joints=model.n_joints, n_wheels=len(model.wheels))
    except (FaultSpecError, PlannerError) as exc:
        raise DemoError(str(exc)) from None


def expected_epoch_s(speed: float, settings: Settings | None = None) -> float:
    """Where the plan's ``t = 0`` will fall, in onboard s from the spacecraft's start, before
    the demo runs (to put a ``--fault`` inside an experiment): the ground puts it ahead of the
    onboard clock at the start request by its start lead (the larger of
    ``uplink_start_lead_s`` and the time for the first command to go up three times,
    ``server.services.runner``) and a second of wall time, rounded up to the 4 Hz grid; the
    demo asks about :data:`CONNECT_WALL_S` after the spacecraft started. The summary's
    ``epoch_onboard_s`` is what it was."""
    from server.services.pass_states import START_SLACK_WALL_S
    from server.services.runner import START_TRANSMISSIONS
    from server.services.uplink import RttEstimator

    s = settings or Settings()
    first_rto_s = RttEstimator(2 * s.link_one_way_delay_s / speed).rto_s
    lead_s = max(
        s.uplink_start_lead_s,
        s.link_one_way_delay_s + s.uplink_margin_s + START_TRANSMISSIONS * first_rto_s * speed,
    )
    return math.ceil((CONNECT_WALL_S * speed + lead_s + START_SLACK_WALL_S * speed) * 4) / 4


def read_truth_log(path: Path) -> list[dict[str, Any]]:
    """The truth log's records (none when there is no file; a line cut short by a stopped
    process is left out)."""
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        return []
    records = []
    for line in text.splitlines():
        with contextlib.suppress(ValueError):
            record = json.loads(line)
            if isinstance(record, dict):
                records.append(record)
    return records


def _truth_start_ns(truth: Sequence[Mapping[str, Any]]) -> int | None:
    start = next((r for r in truth if r.get("event") == "start"), None)
    return None if start is None else int(start["onboard_time_ns"])


def segments_section(
    segments: Sequence[Mapping[str, Any]], epoch_ns: int, clock: OnboardClock
) -> list[dict[str, Any]]:
    """The plan's segments (plan s) with their onboard s since the spacecraft's start."""

    def onboard(t_s: float) -> float | None:
        return clock.since_start_s(epoch_ns + round(t_s * 1e9))

    return [
        {
            "name": s["name"],
            "kind": s["kind"],
            "t_start_s": s["t_start_s"],
            "t_end_s": s["t_end_s"],
            "onboard_start_s": onboard(float(s["t_start_s"])),
            "onboard_end_s": onboard(float(s["t_end_s"])),
        }
        for s in segments
    ]


def _rank(severity: str | None) -> int:
    return 0 if severity is None else SEVERITY_RANK[Severity(severity)]


def alarms_section(alarms: Sequence[Mapping[str, Any]], clock: OnboardClock) -> dict[str, Any]:
    """Every alarm of the pass, oldest raised first, with the times that tell a rehearsal:
    ``raised_frame_s`` (the frame the ground raised it on, generated at that onboard s since
    the spacecraft's start), ``raised_ground_s`` (when the ground raised it, on the onboard
    clock), ``crossings`` (each band reached: the onboard s of the first frame in it, or, for
    the link's health, when the ground saw it) and the timeline so converted; how many went
    above ``watch``. A frame that jumps bands is in the timeline once, at the band it
    reached, and so crosses only that band here."""
    items: list[dict[str, Any]] = []
    for alarm in sorted(alarms, key=lambda a: (a["raised_time_ns"], a["id"])):
        timeline = []
        crossings: dict[str, float | None] = {}
        for step in alarm.get("timeline") or []:
            frame_s = clock.since_start_s(step.get("generation_time_ns"))
            ground_s = clock.ground_s(step.get("time_ns"))
            severity = step.get("severity")
            timeline.append({**step, "frame_s": frame_s, "ground_s": ground_s})
            if severity is not None and severity not in crossings:
                crossings[severity] = frame_s if frame_s is not None else ground_s
        items.append(
            {
                **{k: alarm.get(k) for k in _ALARM_KEYS},
                "raised_frame_s": clock.since_start_s(alarm.get("raised_generation_time_ns")),
                "raised_ground_s": clock.ground_s(alarm.get("raised_time_ns")),
                "crossings": crossings,
                "timeline": timeline,
            }
        )
    by_severity: dict[str, int] = {}
    for item in items:
        by_severity[item["severity"]] = by_severity.get(item["severity"], 0) + 1
    watch = SEVERITY_RANK[Severity.WATCH]
    return {
        "count": len(items),
        "above_watch": sum(1 for item in items if _rank(item["severity"]) > watch),
        "by_severity": by_severity,
        "items": items,
    }


_ALARM_KEYS = (
    "id",
    "quantity",
    "channel",
    "label",
    "unit",
    "source",
    "severity",
    "current_severity",
    "state",
    "limit",
    "trigger_value",
    "worst_value",
    "raised_frame_seq",
    "raised_generation_time_ns",
    "raised_time_ns",
    "detail",
)


def safing_section(
    *,
    record: Mapping[str, Any],
    link: Mapping[str, Any],
    alarms: Sequence[Mapping[str, Any]],
    events: Sequence[Mapping[str, Any]],
    truth: Sequence[Mapping[str, Any]],
    executed: Sequence[Mapping[str, Any]],
    cancelled: Sequence[Mapping[str, Any]],
    clock: OnboardClock,
) -> dict[str, Any]:
    """The vehicle's safing during the demo: from the pass's ``vehicle_safed`` event (the
    trigger, the onboard time it entered SAFE, the commands it dropped), else the link
    status's last ``safing`` report (a spacecraft process lives for one demo: any report is
    of this run); when the ground heard it (its ``vehicle_safing`` alarm was raised on the
    report's arrival; the event is written later, behind the archive's queue) and when the
    pass ended (its ``pass_state`` event); the pass's state and reason; the truth log's
    faults and SAFE entries; ``commands_executed_after_safing``, the pass's executed
    commands whose onboard execution came after the vehicle entered SAFE (must be 0)."""
    report = link.get("safing")
    safed_events = [e for e in events if e["kind"] == "vehicle_safed"]
    first = safed_events[0] if safed_events else None
    source: Mapping[str, Any] = first["detail"] if first is not None else (report or {})
    since_ns = source.get("since_time_ns")
    after = None
    if since_ns is not None:
        after = sum(
            1
            for c in executed
            if c["stage"] == "executed"
            and (c["executed_at_ns"] if c["executed_at_ns"] is not None else c["execute_time_ns"])
            > since_ns
        )
    heard = next(
        (
            a
            for a in alarms
            if a["quantity"] == "vehicle_safing" and a["raised_generation_time_ns"] == since_ns
        ),
        None,
    )
    heard_ns = heard["raised_time_ns"] if heard is not None else None
    if heard_ns is None and first is not None:
        heard_ns = first["time_ns"]
    ended = next(
        (
            e
            for e in events
            if e["kind"] == "pass_state" and e["detail"].get("to") in TERMINAL_STATES
        ),
        None,
    )
    ended_ns = None if ended is None else ended["time_ns"]
    return {
        "safed": since_ns is not None,
        "pass_state": record["state"],
        "pass_reason": record.get("state_reason"),
        "vehicle_mode": link.get("vehicle_mode"),
        "trigger": source.get("trigger"),
        "since_time_ns": since_ns,
        "since_s": clock.since_start_s(since_ns),
        "cancelled_on_board": source.get("cancelled"),
        "ground_heard_time_ns": heard_ns,
        "ground_heard_s": clock.ground_s(heard_ns),
        "pass_ended_time_ns": ended_ns,
        "pass_ended_s": clock.ground_s(ended_ns),
        "last_report": report,
        "events": [
            {
                "kind": e["kind"],
                "time_ns": e["time_ns"],
                "ground_s": clock.ground_s(e["time_ns"]),
                "detail": e["detail"],
            }
            for e in events
            if e["kind"] in _SAFING_EVENTS
            or (e["kind"] == "pass_state" and e["detail"].get("to") in TERMINAL_STATES)
        ],
        "truth_start_ns": clock.start_ns,
        "truth_faults": [r for r in truth if r.get("event") == "fault"],
        "truth_safing": [r for r in truth if r.get("event") in ("safing_entry", "safing_exit")],
        "commands_executed_after_safing": after,
        "commands_cancelled_safing": sum(
            1 for c in cancelled if c["stage"] == "cancelled" and c["reject_reason"] == "safing"
        ),
        "clock_mapping_uncertainty_s": clock.uncertainty_s,
    }


def verdict(summary: Mapping[str, Any]) -> dict[str, Any]:
    """The exit status and what happened. Without faults (a nominal demo): ``ok`` iff the
    pass ended ``complete``, its outcome ``nominal`` (every command executed at its tag:
    docs/operations.md), with no frame missing. With ``--fault``: ``ok`` iff it ended
    ``safed`` or ``complete`` and the run was otherwise sound: every fault began (the truth
    log says so), no frame of the pass's window missing, no command left outstanding, and no
    command executed after the vehicle safed. ``notes`` say what happened (the alarms above
    ``watch``, the faults, the safing), ``problems`` why it is not ``ok``."""
    state = summary["final_state"]
    safing = summary["safing"]
    faults = list(summary.get("faults") or ())
    notes = [_alarms_note(summary["alarms"])]
    problems = []
    for fault in safing["truth_faults"]:
        notes.append(f"fault {fault['spec']} began at onboard {fault['onboard_s']:.2f} s")
    if safing["safed"]:
        notes.append(_safing_note(safing))
    else:
        notes.append("the vehicle never safed itself")
    reason = f": {summary['state_reason']}" if summary.get("state_reason") else ""
    notes.append(f"the pass ended {state}{reason}")
    outcome = summary.get("outcome_text")
    if outcome:
        notes.append(f"outcome {outcome}")
    if faults:
        if state not in ("safed", "complete"):
            problems.append(f"the pass ended {state}, neither safed nor complete")
        from spacecraft.faults import parse_fault

        began = {fault["spec"] for fault in safing["truth_faults"]}
        missed = [spec for spec in faults if parse_fault(spec).spec not in began]
        if missed:
            problems.append(f"never began (the truth log has no onset): {', '.join(missed)}")
        if summary["commands_outstanding"]:
            problems.append(f"{summary['commands_outstanding']} commands still outstanding")
        after = safing["commands_executed_after_safing"]
        if after:
            problems.append(f"{after} commands executed after the vehicle safed")
    elif state != "complete":
        problems.append(f"the pass ended {state}, not complete")
    elif summary.get("outcome") == "degraded":
        problems.append(f"the pass is {outcome}")
    if summary["frames_missing"] != 0:
        problems.append(f"frames missing: {summary['frames_missing']}")
    return {"ok": not problems, "notes": notes, "problems": problems}


def _alarms_note(alarms: Mapping[str, Any]) -> str:
    watch = SEVERITY_RANK[Severity.WATCH]
    above = [a for a in alarms["items"] if _rank(a["severity"]) > watch]
    if not above:
        return f"0 alarms above watch ({alarms['count']} in all)"
    listed = "; ".join(_describe_alarm(a) for a in above)
    return f"{len(above)} alarms above watch: {listed}"


def _describe_alarm(alarm: Mapping[str, Any]) -> str:
    where = " ".join(p for p in (alarm["quantity"], alarm["channel"]) if p)
    bits = []
    if alarm["worst_value"] is not None:
        bits.append(f"worst {alarm['worst_value']:.4g} {alarm['unit']}".rstrip())
    if alarm["limit"] is not None:
        bits.append(f"limit {alarm['limit']:.4g}")
    return f"{where} {alarm['severity']}" + (f" ({', '.join(bits)})" if bits else "")


def _safing_note(safing: Mapping[str, Any]) -> str:
    when = "" if safing["since_s"] is None else f" at onboard {safing['since_s']:.2f} s"
    text = f"the vehicle safed itself{when}"
    trigger = safing["trigger"]
    if trigger:
        where = " ".join(p for p in (trigger["quantity"], trigger["channel"]) if p)
        text += f" ({where} {trigger['value']:.4g} beyond {trigger['limit']:.4g})"
    if safing["cancelled_on_board"] is not None:
        text += f", dropping {safing['cancelled_on_board']} commands"
    after = safing["commands_executed_after_safing"]
    return text + f"; {after if after is not None else 'unknown'} executed after"
