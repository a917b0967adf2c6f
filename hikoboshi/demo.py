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
   and the MCAP recording (``pass.mcap``) are written to ``OUT`` (not with ``--no-reports``:
   the summary alone, seconds sooner; ``hikoboshi report`` and ``hikoboshi mcap export`` make
   them later from the database).

Faults (``--fault SPEC``, repeatable, :mod:`spacecraft.faults`'s grammar) go to the
spacecraft process as they are; it always writes its truth log to ``OUT/truth.jsonl``. The
summary adds what the pass's limits and the vehicle's own protection did:

- ``alarms``: every alarm of the pass (``GET /api/alarms?pass=``), each with its bands'
  crossings from its timeline, and how many went above ``watch``;
- ``safing``: the vehicle's safing as the ground heard it (the link status's last ``safing``
  report, the pass's ``vehicle_safed`` event and its state), the truth log's faults and
  safing entries, and the pass's commands executed on board after the vehicle safed (the
  vehicle's rule makes it 0);
- ``verdict``: the exit status's reasons (:func:`hikoboshi.demo_summary.verdict`).

Onboard times are also given as seconds since the spacecraft's start (the truth log's
``start``, the origin of ``--fault`` and ``--outage`` times), and the ground's own times
on the onboard clock through the link's clock mapping, sampled while the pass ran.

With a robot description the ground is given the file (``Settings.robot_files``, as
``hikoboshi serve --robot``), the plan request names the robot, and the spacecraft flies
the same file (``hikoboshi spacecraft --robot``): the ground checks that the vehicle's
``hello`` names the robot the plan was made for before it starts the pass.

Only public interfaces are used: REST, the link websocket, process signals
(:mod:`hikoboshi.demo_harness`, shared with the campaign demo); the summary's sections
are :mod:`hikoboshi.demo_summary`'s.
"""

from __future__ import annotations

import contextlib
import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

from hikoboshi.demo_harness import (
    DemoError,
    Progress,
    _all,
    _Api,
    _ClockSampler,
    _drain,
    _follow,
    _ground,
    _port,
    _settle,
    _spacecraft,
    _start,
    _token_of,
    _tokens,
    _wait_connected,
    spacecraft_command,
)
from hikoboshi.demo_summary import (
    OnboardClock,
    _truth_start_ns,
    alarms_section,
    read_truth_log,
    safing_section,
    segments_section,
    verdict,
)
from server.settings import Role, Settings
from server.storage.db import sqlite_url

__all__ = ["CONNECT_WALL_S", "DemoOptions", "check_fault_specs", "expected_epoch_s", "run_demo"]


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
    #: With ``serve_after``: called with the summary (and its verdict) once the pass is over,
    #: before the service goes on serving until Ctrl-C.
    on_summary: Callable[[dict[str, Any]], None] | None = None
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
    #: The post-pass analyses, report and recording; False: the summary alone.
    reports: bool = True


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
            *spacecraft_command(port, options),
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
            epoch_ns = _start(api, pass_id, name)
            state = _follow(
                api, proc, pass_id, epoch_ns, duration_s, options.timeout_s, report, sampler
            )
            _settle(api, pass_id, options.speed)
            # the vehicle's mode as the pass left it (the spacecraft is still connected)
            link_end = api.call("GET", "/api/link/status")
            _drain(proc, report)
        summary = api.call("GET", f"/api/passes/{pass_id}/summary")
        link = api.call("GET", "/api/link/status")
        truth = read_truth_log(truth_log)
        clock = sampler.clock(_truth_start_ns(truth))
        sections = _limits_and_safing(api, pass_id, link_end, truth, clock)
        failed = _reports(api, pass_id, out, report) if options.reports else []
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
            **{
                key: str((out / name).resolve()) if options.reports else None
                for key, name in REPORT_FILES.items()
            },
            "console_url": f"{base}/",
            "tokens_file": str((out / "tokens").resolve()),
            "api_docs_url": f"{base}/docs",
            "pass_url": f"{base}/api/passes/{pass_id}",
            "summary_url": f"{base}/api/passes/{pass_id}/summary",
        }
        result["verdict"] = verdict(result)
        (out / "summary.json").write_text(json.dumps(result, indent=2) + "\n")
        if options.serve_after:
            # the verdict first: what the operator waits for is printed before the serving
            if options.on_summary is not None:
                options.on_summary(result)
            report(f"serving {base}/ until Ctrl-C", 0, 1)
            with contextlib.suppress(KeyboardInterrupt):
                while True:
                    time.sleep(1.0)
    return result


#: The summary's keys of the files the post-pass step writes to ``OUT``.
REPORT_FILES = {
    "report_html": "report.html",
    "report_json": "report.json",
    "recording_mcap": "pass.mcap",
}


def _reports(api: _Api, pass_id: str, out: Path, report: Progress) -> list[str]:
    """The post-pass analyses on the server, the report and the MCAP recording written to
    ``out``; the kinds of the analyses that failed."""
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
    return failed


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


#: Wall s from the spacecraft's start to the demo's start request (the process connects
#: and says hello; the demo polls the link every 0.1 s): 0.19 measured at 20x on a loaded
#: 2-core machine (the plan's t = 0 came at 76.75 s).
CONNECT_WALL_S = 0.2


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
    the demo runs (to put a ``--fault`` inside an experiment): the ground puts it on the
    0.25 s grid at most its start lead after the onboard clock at the start request
    (:func:`server.operations.windows.start_lead_s` at the demo's speed: the larger of
    ``uplink_start_lead_s`` and the time for the first command to go up three times, a
    second of wall time and the grid step); the demo asks about :data:`CONNECT_WALL_S`
    after the spacecraft started. The summary's ``epoch_onboard_s`` is what it was."""
    from server.operations.windows import start_lead_s

    lead_s = start_lead_s(settings or Settings(), speed)
    return math.floor((CONNECT_WALL_S * speed + lead_s) * 4) / 4
