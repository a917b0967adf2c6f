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

With a robot description the ground is given the file (``Settings.robot_files``, as
``hikoboshi serve --robot``), the plan request names the robot, and the spacecraft flies
the same file (``hikoboshi spacecraft --robot``): the ground checks that the vehicle's
``hello`` names the robot the plan was made for before it starts the pass.

Only public interfaces are used: REST, the link websocket, process signals.
"""

from __future__ import annotations

import contextlib
import json
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
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import uvicorn

from server.app import create_app
from server.settings import ApiToken, Role, Settings
from server.storage.db import sqlite_url

__all__ = ["DemoError", "DemoOptions", "run_demo"]

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
    #: Called once the service is up: (console URL, viewer token, operator token).
    on_ready: Callable[[str, str, str], None] | None = None
    extra_spacecraft_args: tuple[str, ...] = field(default=())
    #: A robot description (TOML) to fly instead of the built-in ETS-VII.
    robot: Path | None = None


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
    config = uvicorn.Config(
        create_app(settings), host="127.0.0.1", port=port, log_level="warning", lifespan="on"
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


@contextmanager
def _spacecraft(args: list[str], log_path: Path) -> Iterator[subprocess.Popen[bytes]]:
    with log_path.open("wb") as log:
        proc = subprocess.Popen(args, stdout=log, stderr=subprocess.STDOUT)
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
    out.mkdir(parents=True, exist_ok=True)
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
    settings = Settings(data_dir=out, tokens=tokens, robot_files=() if robot is None else (robot,))
    started = time.monotonic()
    with _ground(settings, port):
        api = _Api(base, operator)
        if options.on_ready is not None:
            options.on_ready(f"{base}/", _token_of(tokens, Role.VIEWER), operator)
        report("planning the pass (all four experiments)", 0, 1)
        parameters = {"experiments": list(options.experiments)} if options.experiments else {}
        request: dict[str, Any] = {"experiment": "pass", "parameters": parameters}
        if robot_name is not None:
            request["robot"] = robot_name
        plan = api.call("POST", "/api/plans", request)
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
            sys.executable,
            "-m",
            "hikoboshi",
            "spacecraft",
            "--ground",
            f"ws://127.0.0.1:{port}/api/link",
            "--token",
            _token_of(tokens, Role.SPACECRAFT),
            "--time-scale",
            repr(options.speed),
            "--loss",
            repr(options.loss),
            "--seed",
            str(options.seed),
            *(a for o in options.outages for a in ("--outage", o)),
            *(() if robot is None else ("--robot", str(robot))),
            *options.extra_spacecraft_args,
        ]
        with _spacecraft(args, out / "spacecraft.log") as proc:
            _wait_connected(api, proc)
            started_pass = api.call(
                "POST", f"/api/passes/{pass_id}/start", {"confirm": f"START {name}"}
            )
            epoch_ns = int(started_pass["epoch_ns"])
            state = _follow(api, proc, pass_id, epoch_ns, duration_s, options, report)
            _settle(api, pass_id)
            report("draining the onboard telemetry store", 0, 1)
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout=120.0)
            except subprocess.TimeoutExpired:
                raise DemoError("the spacecraft did not drain its telemetry in 120 s") from None
            report("draining the onboard telemetry store", 1, 1)
        summary = api.call("GET", f"/api/passes/{pass_id}/summary")
        link = api.call("GET", "/api/link/status")
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
        "viewer_token": _token_of(tokens, Role.VIEWER),
        "api_docs_url": f"{base}/docs",
        "pass_url": f"{base}/api/passes/{pass_id}",
        "summary_url": f"{base}/api/passes/{pass_id}/summary",
    }
    (out / "summary.json").write_text(json.dumps(result, indent=2) + "\n")
    return result


def _wait_connected(api: _Api, proc: subprocess.Popen[bytes]) -> None:
    deadline = time.monotonic() + 60.0
    while not api.call("GET", "/api/link/status")["connected"]:
        if proc.poll() is not None:
            raise DemoError(f"the spacecraft process exited with {proc.returncode}")
        if time.monotonic() > deadline:
            raise DemoError("the spacecraft did not connect within 60 s")
        time.sleep(0.1)


def _settle(api: _Api, pass_id: str, timeout_s: float = 60.0) -> None:
    """Before the spacecraft stops: let the onboard clock pass the end of the pass's
    telemetry window (every frame of it generated; the drain delivers them) and the
    ground resolve the commands still in flight (an abort leaves some)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        summary = api.call("GET", f"/api/passes/{pass_id}/summary")
        onboard = api.call("GET", "/api/link/status").get("onboard_time_ns")
        end = summary["telemetry_end_ns"]
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
) -> str:
    """Poll the pass until it ends; its final state."""
    deadline = time.monotonic() + options.timeout_s
    while True:
        record = api.call("GET", f"/api/passes/{pass_id}")
        if record["state"] in ("complete", "aborted"):
            report("pass", duration_s, duration_s)
            return str(record["state"])
        if proc.poll() is not None:
            raise DemoError(f"the spacecraft process exited with {proc.returncode} mid-pass")
        if time.monotonic() > deadline:
            raise DemoError(f"the pass did not end within {options.timeout_s:.0f} s")
        status = api.call("GET", "/api/link/status")
        onboard = status.get("onboard_time_ns")
        if onboard is not None:
            t_s = min(duration_s, max(0.0, (onboard - epoch_ns) / 1e9))
            report("pass", t_s, duration_s)
        time.sleep(0.25)
