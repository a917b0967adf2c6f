"""The campaign demo: a mission's passes flown back to back across its computed windows
(``hikoboshi demo --campaign``; docs/missions.md "The campaign demo").

1. The campaign: ``server.operations.campaign.plan_campaign`` (the experiments assigned to
   consecutive windows, each pass's predicted start state and the wheel momentum gravity
   gradient loads between passes), each pass planned once: its plan document is uploaded
   (``POST /api/plans/documents``), the ground checks it and flies its commands; or, given
   experiments per pass (a shorter campaign: the tests), those planned by the ground
   (``POST /api/plans``) over the first windows that hold them, with no prediction.
2. The ground service starts (as ``hikoboshi demo``), the spacecraft process starts with
   ``--mission`` and the campaign's windows (``--windows``): its onboard second 0 is the
   campaign's start in UTC, its link is up only inside those windows with the geometry's
   delay, and it flies the time before and between windows in FAST mode.
3. For each pass: its stored plan (uploaded, or planned by the ground), the pass scheduled
   in its window (``POST /api/passes`` naming the window); once the onboard clock reaches
   the window's net start the operator starts it; the job follows it to its end.
4. The spacecraft stops; each pass's summary, analyses and report go to ``OUT/pass-N/``
   (after the last pass: one pass's analyses may outlast the gap to the next window);
   ``OUT/campaign.json`` and ``OUT/campaign.md`` hold per pass the
   window, the commands executed at their tag, expired, and sent outside a window, and per
   gap the wheel momentum carried across it as measured (the ground's telemetry at the end
   of one pass and the start of the next) against the campaign's prediction.

The relay is booked per pass, as TDRS time was: from the window's AOS to the end of its
pass and a service tail (:mod:`hikoboshi.campaign_passes`, with the options and which
passes fly where); the rest is flown fast. The report is :mod:`hikoboshi.campaign_report`'s,
the ground and the spacecraft are run as by ``hikoboshi demo`` (:mod:`hikoboshi.demo_harness`).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

from hikoboshi.campaign_passes import (
    CampaignOptions,
    _campaign,
    _PassSpec,
    _service_windows,
)
from hikoboshi.campaign_report import _campaign_doc, _fmt, _utc, campaign_markdown
from hikoboshi.demo_harness import (
    DemoError,
    Progress,
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
    spacecraft_command,
)
from hikoboshi.demo_summary import read_truth_log
from server.settings import Role, Settings

__all__ = ["StoredPlans", "run_campaign_demo"]


def run_campaign_demo(options: CampaignOptions, progress: Progress | None = None) -> dict[str, Any]:
    """Fly the campaign; its report (also ``OUT/campaign.json`` and ``OUT/campaign.md``)."""
    from mission import format_utc, load_mission

    report = progress or (lambda phase, done, total: None)
    out = options.out
    out.mkdir(parents=True, exist_ok=True)
    mission = load_mission(options.mission)
    started = time.monotonic()
    tokens = _tokens(out)
    operator = _token_of(tokens, Role.OPERATOR)
    port = _port(options.port)
    base = f"http://127.0.0.1:{port}"
    # Three uploaded passes checked again by the ground: on a loaded 2-core machine a
    # whole pass's planning took over the default 120 s deadline.
    settings = Settings(
        data_dir=out,
        tokens=tokens,
        missions_dir=options.mission.parent.resolve(),
        plan_deadline_s=900.0,
        post_pass_deadline_s=1800.0,
        # the windows are the mission's day, which the vehicle's clock reads (its onboard
        # clock starts at the campaign's start, UTC), not the ground's wall (docs/missions.md)
        window_clock="vehicle",
    )
    truth_log = out / "truth.jsonl"
    results: list[dict[str, Any]] = []
    flown_passes: list[tuple[int, str, str, _PassSpec, Any, int, float]] = []
    with _ground(settings, port):
        api = _Api(base, operator)
        plans = StoredPlans(api, options.pass_parameters)
        report("planning the campaign", 0, 1)
        specs = _campaign(options, lambda e: float(plans.of_experiments(e)["duration_s"]))
        report("planning the campaign", 1, 1)
        report("the ground stores and checks each pass's plan", 0, len(specs))
        for k, spec in enumerate(specs, start=1):
            plans.of(spec)
            report("the ground stores and checks each pass's plan", k, len(specs))
        flown = _service_windows(
            specs,
            [float(plans.of(s)["duration_s"]) for s in specs],
            options.speed,
            options.service_tail_s,
        )
        windows_file = out / "windows.json"
        windows_file.write_text(
            json.dumps({"windows": [w.to_dict() for w in flown]}, indent=2) + "\n"
        )
        args = [
            *spacecraft_command(port, options),
            "--mission",
            str(options.mission.resolve()),
            "--mission-start",
            options.start_utc.isoformat(),
            "--windows",
            str(windows_file.resolve()),
            *(() if options.fast_scale is None else ("--fast-scale", repr(options.fast_scale))),
            "--truth-log",
            str(truth_log.resolve()),
        ]
        token_env = {"HIKOBOSHI_SPACECRAFT_TOKEN": _token_of(tokens, Role.SPACECRAFT)}
        with _spacecraft(args, out / "spacecraft.log", token_env) as proc:
            start_ns = _truth_start(truth_log, proc)
            for i, (spec, window) in enumerate(zip(specs, flown, strict=True), start=1):
                plan = plans.of(spec)
                duration_s = float(plan["duration_s"])
                name = f"{mission.name} pass {i} {format_utc(window.aos_utc)}"
                record = api.call(
                    "POST",
                    "/api/passes",
                    {
                        "plan_id": plan["id"],
                        "name": name,
                        "window": {
                            "mission": mission.name,
                            "relay": window.relay,
                            "aos_time": window.aos_utc.isoformat(),
                        },
                    },
                )
                pass_id = record["id"]
                net_start_s = (window.net_start_utc - options.start_utc).total_seconds()
                phase = f"pass {i}: waiting for {window.relay}'s window"
                _wait_onboard(api, proc, start_ns, net_start_s, options, report, phase)
                epoch_ns = _start(api, pass_id, name)
                state = _follow(
                    api,
                    proc,
                    pass_id,
                    epoch_ns,
                    duration_s,
                    options.timeout_s,
                    _relabel(report, f"pass {i} (onboard s)"),
                    _ClockSampler(),
                )
                _settle(api, pass_id, options.speed)
                # the reports wait for the end: the next window does not
                flown_passes.append((i, pass_id, state, spec, window, epoch_ns, duration_s))
            _drain(proc, report)
        for i, pass_id, state, spec, window, epoch_ns, duration_s in flown_passes:
            report("per-pass summaries and reports", i - 1, len(flown_passes))
            results.append(
                _pass_result(
                    api,
                    out / f"pass-{i}",
                    i,
                    pass_id,
                    state,
                    spec,
                    window,
                    epoch_ns,
                    duration_s,
                    start_ns,
                    options,
                )
            )
        report("per-pass summaries and reports", len(flown_passes), len(flown_passes))
    truth = read_truth_log(truth_log)
    doc = _campaign_doc(options, mission, results, specs, truth, start_ns)
    doc["wall_time_s"] = round(time.monotonic() - started, 1)
    (out / "campaign.json").write_text(json.dumps(doc, indent=2) + "\n")
    (out / "campaign.md").write_text(campaign_markdown(doc))
    return doc


class StoredPlans:
    """Each pass's plan stored on the ground, once per parameters: the campaign's document
    uploaded (``POST /api/plans/documents``: the ground predicts and checks it again, and
    flies its commands), else the ground plans the pass (``POST /api/plans``) of the
    experiments with ``pass_parameters``. Planning and checking run in the ground's workers:
    minutes when the machine is loaded."""

    def __init__(self, api: _Api, pass_parameters: dict[str, Any] | None = None) -> None:
        self._api = api
        self._pass_parameters = pass_parameters or {}
        self._plans: dict[str, dict[str, Any]] = {}

    def _stored(self, parameters: dict[str, Any], document: str | None) -> dict[str, Any]:
        key = json.dumps(parameters, sort_keys=True)
        if key not in self._plans:
            if document is not None:
                self._plans[key] = self._api.call(
                    "POST", "/api/plans/documents", data=document.encode(), timeout_s=900.0
                )
            else:
                body = {"experiment": "pass", "parameters": parameters}
                self._plans[key] = self._api.call("POST", "/api/plans", body, timeout_s=900.0)
        return self._plans[key]

    def of_experiments(self, experiments: tuple[str, ...]) -> dict[str, Any]:
        """The ground's plan of a pass of ``experiments`` from the nominal start."""
        return self._stored({"experiments": list(experiments), **self._pass_parameters}, None)

    def of(self, spec: _PassSpec) -> dict[str, Any]:
        """``spec``'s plan: its document uploaded, else the ground's of its experiments."""
        if spec.parameters is not None:
            return self._stored(spec.parameters, spec.document)
        return self.of_experiments(spec.experiments)


def _relabel(report: Progress, phase: str) -> Progress:
    def relabelled(_phase: str, done: float, total: float) -> None:
        report(phase, done, total)

    return relabelled


def _truth_start(path: Path, proc: Any) -> int:
    """The spacecraft's onboard ns at its start (the truth log's first record)."""
    deadline = time.monotonic() + 60.0
    while True:
        records = read_truth_log(path)
        start = next((r for r in records if r.get("event") == "start"), None)
        if start is not None:
            return int(start["onboard_time_ns"])
        if proc.poll() is not None:
            raise DemoError(f"the spacecraft process exited with {proc.returncode}")
        if time.monotonic() > deadline:
            raise DemoError("the spacecraft wrote no start to its truth log within 60 s")
        time.sleep(0.1)


def _wait_onboard(
    api: _Api,
    proc: Any,
    start_ns: int,
    at_s: float,
    options: CampaignOptions,
    report: Progress,
    phase: str,
) -> None:
    """Until the spacecraft is connected and its clock (as the ground reads it) is at or
    past ``at_s`` onboard s since its start."""
    deadline = time.monotonic() + options.timeout_s + at_s / options.speed
    while True:
        status = api.call("GET", "/api/link/status")
        onboard = status.get("onboard_time_ns")
        now_s = None if onboard is None else (onboard - start_ns) / 1e9
        if now_s is not None:
            report(phase, min(now_s, at_s), at_s)
        if status.get("connected") and now_s is not None and now_s >= at_s:
            return
        if proc.poll() is not None:
            raise DemoError(f"the spacecraft process exited with {proc.returncode}")
        if time.monotonic() > deadline:
            raise DemoError(f"{phase}: the onboard clock did not reach {at_s:.0f} s")
        time.sleep(0.1)


def _momentum_at(api: _Api, pass_id: str, t_ns: int, *, before: bool) -> list[float] | None:
    """The wheel momentum (N m s, base frame) of the pass's first frame at or after
    ``t_ns``, or (``before``) its last frame before it (within a second)."""
    t0 = t_ns - 10**9 if before else t_ns
    t1 = t_ns if before else t_ns + 10**9
    body = api.call(
        "GET", f"/api/passes/{pass_id}/telemetry?t0={t0}&t1={t1}&fields=hw1,hw2,hw3&limit=100"
    )
    rows = body.get("rows") or []
    if not rows:
        return None
    row = rows[-1] if before else rows[0]
    return [float(row["values"][k]) for k in ("hw1", "hw2", "hw3")]


def _pass_result(
    api: _Api,
    where: Path,
    index: int,
    pass_id: str,
    state: str,
    spec: _PassSpec,
    window: Any,
    epoch_ns: int,
    duration_s: float,
    start_ns: int,
    options: CampaignOptions,
) -> dict[str, Any]:
    """The pass's summary and report under ``where``; its line of the campaign report."""
    where.mkdir(parents=True, exist_ok=True)
    summary = api.call("GET", f"/api/passes/{pass_id}/summary")
    failed: list[str] = []
    analyses_error = None
    try:  # the pass's line of the campaign report does not depend on its analyses
        analyses = api.call("POST", f"/api/passes/{pass_id}/analyses", timeout_s=900.0)
        failed = [a["kind"] for a in analyses["data"] if a["status"] != "ok"]
        (where / "report.html").write_bytes(api.raw("GET", f"/api/passes/{pass_id}/report.html"))
        (where / "report.json").write_bytes(api.raw("GET", f"/api/passes/{pass_id}/report"))
    except (DemoError, OSError) as exc:
        analyses_error = str(exc)[:500]
    (where / "summary.json").write_text(
        json.dumps(
            {
                **summary,
                "final_state": state,
                "analyses_failed": failed,
                "analyses_error": analyses_error,
            },
            indent=2,
        )
        + "\n"
    )
    end_ns = epoch_ns + round(duration_s * 1e9)
    epoch_s = (epoch_ns - start_ns) / 1e9
    return {
        "pass": index,
        "pass_id": pass_id,
        "experiments": list(spec.experiments),
        "window": spec.window.to_dict(),
        "service_los_utc": _fmt(window.los_utc),
        "state": state,
        "outcome": summary.get("outcome"),
        "outcome_text": summary.get("outcome_text"),
        "plan_duration_s": duration_s,
        "epoch_onboard_s": round(epoch_s, 3),
        "epoch_utc": _utc(options.start_utc, epoch_s),
        "end_utc": _utc(options.start_utc, epoch_s + duration_s),
        "commands_total": summary["commands_total"],
        "commands_executed_at_tag": summary["commands_executed_at_tag"],
        "commands_executed_late": summary["commands_executed_late"],
        "commands_expired": summary["commands_expired"],
        "commands_rejected": summary["commands_rejected"],
        "commands_retransmitted": summary["commands_retransmitted"],
        "frames_missing": summary["frames_missing"],
        "analyses_failed": failed,
        "analyses_error": analyses_error,
        "frames_stored": summary["frames_stored"],
        "frames_expected": summary["frames_expected"],
        "wheel_momentum_start_nms": _momentum_at(api, pass_id, epoch_ns, before=False),
        "wheel_momentum_end_nms": _momentum_at(api, pass_id, end_ns, before=True),
        "predicted_gap_momentum_nms": spec.gap_momentum_nms,
        "predicted_wheel_momentum_start_nms": spec.predicted_start_h,
        "predicted_wheel_momentum_end_nms": spec.predicted_end_h,
        "report_html": str((where / "report.html").resolve()),
        "summary_json": str((where / "summary.json").resolve()),
        "_span_s": (epoch_s, epoch_s + duration_s),
    }
