"""``hikoboshi demo``: the main job end to end (ground service, spacecraft process, a pass).

The README's command flies the whole schedule; here one experiment keeps it short, through
the same code path: Orihime (seven joints) with 10 % loss and a 30 s outage inside the pass,
and the six-joint robot with a joint stuck.
"""

from __future__ import annotations

import contextlib
import importlib.util
import json
import re
import sqlite3
import stat
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from hikoboshi.demo import CONNECT_WALL_S, check_fault_specs, expected_epoch_s
from hikoboshi.demo_harness import DemoError
from hikoboshi.demo_summary import (
    OnboardClock,
    alarms_section,
    read_truth_log,
    safing_section,
    segments_section,
    verdict,
)
from spacecraft.faults import parse_fault

#: The two demo runs fly a vehicle in wall time: they are ``realtime`` (tests/conftest.py);
#: the refusals (a demo that stops before starting anything) and the summary's sections (no
#: flight) are not, and run beside the real-time chain (10 s of it with one core busy).
realtime = pytest.mark.realtime


def _ptp_demo(out: Path, *options: str, streams: list[str] | None = None) -> dict[str, Any]:
    """``hikoboshi demo --experiments ptp --speed 20 --json`` with ``options``, into ``out``:
    its summary, which must be the one written to ``out/summary.json``, and status 0; its
    stdout and stderr are added to ``streams``."""
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "hikoboshi",
            "demo",
            "--experiments",
            "ptp",
            "--speed",
            "20",
            *options,
            "--port",
            "0",
            "--json",
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    if streams is not None:
        streams += [result.stdout, result.stderr]
    assert result.returncode == 0, result.stderr[-3000:]
    summary: dict[str, Any] = json.loads(result.stdout)
    assert summary == json.loads((out / "summary.json").read_text())
    return summary


ORIHIME = Path(__file__).resolve().parents[1] / "examples" / "robots" / "orihime" / "orihime.toml"


@realtime
@pytest.mark.slow
def test_demo_flies_orihime_through_loss_and_an_outage_losing_no_frame_and_no_command(
    tmp_path: Path,
) -> None:
    """``demo --robot`` through 10 % loss and a 30 s outage: the ground plans Orihime's pass
    (PTP only, to keep it short) through REST, the spacecraft process flies Orihime, the
    ground checked their robots agree, and no frame and no command of the pass is lost.
    (One demo run for both: each run is some 35 s of start-up, planning and reports around
    13 s of flight; the six-joint robot's demo is flown by the joint-stuck test below.)"""
    out = tmp_path / "demo"
    streams: list[str] = []
    summary = _ptp_demo(
        out, "--robot", str(ORIHIME), "--loss", "0.1", "--outage", "100:130", streams=streams
    )
    assert summary["final_state"] == "complete"
    assert (summary["robot"], summary["vehicle_robot"]) == ("orihime", "orihime")
    # every frame of the pass's window once, although 10 % of the messages and 30 s of the
    # link were lost: resends and retransmit requests filled every gap
    assert summary["frames_expected"] > 1000
    assert summary["frames_stored"] == summary["frames_expected"]
    assert summary["frames_missing"] == 0 and summary["gaps_open"] == 0
    assert summary["duplicates_stored"] == 0
    # the losses were real and the ground asked for what it missed. Copies of frames it
    # already held (duplicates_dropped, bounded below) may be none: the ground asks for gaps
    # within a second and its cumulative acks cover lost ones, all before the spacecraft's
    # resend timer (10 s onboard + 3 s of wall per unit of scale); 0 was seen once in a run
    # with one core busy
    assert summary["retransmit_requests"] > 0
    # Every command executed at its tag although 10 % of the messages and 30 s of the link
    # were lost: the windowed uplink had loaded the outage's commands ahead and sent the
    # lost ones again (the bound on copies: 2 x loss x frames).
    assert summary["commands_total"] > 400
    assert summary["commands_executed"] == summary["commands_total"]
    assert summary["commands_executed_at_tag"] == summary["commands_total"]
    assert summary["commands_expired"] == 0 and summary["commands_rejected"] == {}
    assert summary["commands_outstanding"] == 0 and summary["commands_cancelled"] == 0
    assert summary["outcome"] == "nominal" and summary["commands_unresolved"] == 0
    assert summary["commands_retransmitted"] > 0
    assert summary["min_command_lead_s"] > 5.0  # each was on board before its last chance
    assert summary["duplicates_dropped"] <= 2 * 0.1 * summary["frames_expected"]
    # no false alarm (the must-show) and no safing; the verdict says so
    assert summary["alarms"]["above_watch"] == 0, summary["verdict"]["notes"][0]
    assert summary["verdict"]["notes"][0].startswith("0 alarms above watch")
    assert summary["verdict"]["ok"] and summary["faults"] == []
    assert not summary["safing"]["safed"] and summary["safing"]["truth_faults"] == []
    assert summary["safing"]["vehicle_mode"] == "nominal"
    # the truth log was written: onboard s from the spacecraft's start, and the plan's t = 0
    # no earlier than the ground's lead (the demo's own time to connect comes on top)
    truth = [json.loads(line) for line in (out / "truth.jsonl").read_text().splitlines()]
    assert [r["event"] for r in truth] == ["start", "link"]  # the link's counts at the end
    lead_s = expected_epoch_s(20.0) - CONNECT_WALL_S * 20.0
    assert lead_s - 0.25 <= summary["epoch_onboard_s"] <= lead_s + 60.0  # a guard above
    ptp = next(s for s in summary["segments"] if s["name"] == "ptp: A->B")
    assert ptp["onboard_start_s"] == summary["epoch_onboard_s"]
    # the outage fell inside the pass (Orihime's motion, 10 s, ends before it; its settle
    # commands went on at 4 Hz through it)
    assert ptp["onboard_start_s"] < 100.0 and summary["segments"][-1]["onboard_end_s"] > 130.0
    # the main job leaves what it needs to be looked at again, tokens private
    assert Path(summary["database"]).exists()
    assert (out / "pass.mcap").read_bytes()[:8] == b"\x89MCAP0\r\n"
    report = json.loads((out / "report.json").read_text())
    assert report and "<html" in (out / "report.html").read_text().lower()
    assert stat.S_IMODE((out / "tokens").stat().st_mode) == 0o600
    # No token in any log of the run: its stdout (the summary), its stderr (the ground's
    # log), and every file it wrote but the tokens file itself (the spacecraft's log, the
    # database with its audit log, the summary, the report, the recording).
    assert summary["tokens_file"] == str((out / "tokens").resolve())
    assert _tokens_in_logs(out, streams) == []
    assert "connected to ws://127.0.0.1" in (out / "spacecraft.log").read_text()
    # the plan, the commands and the telemetry are Orihime's seven joints
    with contextlib.closing(sqlite3.connect(out / "hikoboshi.sqlite3")) as db:
        plan = json.loads(db.execute("SELECT document FROM plans").fetchone()[0])
    assert plan["robot"] == "orihime" and len(plan["initial_joints_rad"]) == 7
    assert {a["kind"]: a["status"] for a in report["analyses"]}["pass_analysis"] == "ok"
    from mcap.reader import make_reader

    with (out / "pass.mcap").open("rb") as f:
        reader = make_reader(f)
        urdf = next(iter(reader.iter_attachments())).data.decode()
        assert urdf.count('type="revolute"') == 7
        telemetry = next(
            json.loads(message.data)
            for _, channel, message in reader.iter_messages(topics=["/hikoboshi/telemetry"])
        )
    assert len(telemetry["joints_rad"]) == 7


def _tokens_in_logs(out: Path, streams: list[str]) -> list[str]:
    """Where the demo's tokens (``out/tokens``: the operator's, the viewer's and the
    spacecraft's) appear in ``streams`` or in a file under ``out`` other than that one."""
    line = (out / "tokens").read_text().strip()
    tokens = {item.partition("=")[2]: item.partition("=")[0] for item in line.split(",")}
    assert len(tokens) == 3 and all(len(token) >= 16 for token in tokens.values()), tokens
    texts = {f"stream {i}": text for i, text in enumerate(streams)}
    assert any(texts.values())  # something was written to look in
    for path in sorted(out.rglob("*")):
        if path.is_file() and path.name != "tokens":
            texts[str(path.relative_to(out))] = path.read_bytes().decode("latin-1")
    assert "spacecraft.log" in texts and "hikoboshi.sqlite3" in texts
    return [
        f"{holder}'s token in {where}"
        for where, text in texts.items()
        for holder, token in tokens.items()
        if token in text
    ]


@realtime
@pytest.mark.slow
def test_demo_with_a_joint_stuck_in_the_ptp_motion_ends_safed_and_says_when(
    tmp_path: Path,
) -> None:
    """``demo --fault``: joint 3 stuck a fifth of the way through the PTP motion (its plan
    time after the ground's lead): the vehicle safes itself, the pass ends safed with every
    band's crossing, the ground's alarm and the safing in the summary, and status 0. With
    ``--no-reports``: the summary alone (the analyses, report and recording are the Orihime
    test's above; 6-10 s of this one's wall time, none of them asserted here)."""
    at_s = expected_epoch_s(20.0) + 0.2 * 53.75
    out = tmp_path / "demo"
    summary = _ptp_demo(out, "--fault", f"joint3-stuck@{at_s:g}", "--no-reports")
    assert summary["verdict"]["ok"] and summary["final_state"] == "safed"
    assert summary["analyses_failed"] == [] and summary["report_html"] is None
    assert not any((out / name).exists() for name in ("report.html", "report.json", "pass.mcap"))
    safing = summary["safing"]
    (fault,) = safing["truth_faults"]
    assert fault["spec"] == f"joint3-stuck@{at_s:g}"
    assert fault["onboard_s"] == pytest.approx(at_s, abs=0.01)  # the first 10 ms step
    ptp = next(s for s in summary["segments"] if s["name"] == "ptp: A->B")
    assert ptp["onboard_start_s"] < at_s < ptp["onboard_end_s"]
    # the vehicle safed on its own tracking error, after the fault; nothing executed after
    assert safing["safed"] and safing["pass_state"] == "safed"
    assert (safing["trigger"]["quantity"], safing["trigger"]["channel"]) == (
        "joint_tracking_error_deg",
        "joint3",
    )
    (entry,) = [r for r in safing["truth_safing"] if r["event"] == "safing_entry"]
    assert safing["since_s"] == pytest.approx(entry["onboard_s"]) and safing["since_s"] > at_s
    assert safing["commands_executed_after_safing"] == 0
    assert safing["commands_cancelled_safing"] > 0 and safing["vehicle_mode"] == "safe"
    # the ground heard it after the relay's delay (3 s one way, onboard)
    assert safing["ground_heard_s"] > safing["since_s"] + 2.5
    # the ground's alarm: every band crossed in order, the critical one on the vehicle's own
    # detection or the frame before; raised on the first frame in a band
    alarms = {(a["quantity"], a["channel"]): a for a in summary["alarms"]["items"]}
    tracking = alarms[("joint_tracking_error_deg", "joint3")]
    crossings = tracking["crossings"]
    assert tracking["severity"] == "critical" and "critical" in crossings
    assert list(crossings.values()) == sorted(crossings.values())
    assert at_s < crossings[next(iter(crossings))] == tracking["raised_frame_s"]
    assert 0.0 <= safing["since_s"] - crossings["critical"] <= 0.1 + 1e-9
    assert alarms[("vehicle_safing", "")]["raised_frame_s"] == safing["since_s"]
    assert summary["alarms"]["above_watch"] >= 2


def test_demo_refuses_bad_options_before_starting_anything(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    for args, words in (
        (["--speed", "0"], "--speed"),
        (["--loss", "1.5"], "--loss"),
        (["--outage", "70:40"], "--outage"),
    ):
        result = subprocess.run(
            [sys.executable, "-m", "hikoboshi", "demo", "--out", str(out), *args],
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert result.returncode == 2, result.stderr
        assert words in result.stderr
        assert not out.exists()


def test_demo_refuses_a_bad_robot_description_before_starting_anything(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "x"\n')
    result = subprocess.run(
        [sys.executable, "-m", "hikoboshi", "demo", "--out", str(out), "--robot", str(bad)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 2, result.stderr
    assert result.stderr.startswith(f"error: {bad}: ")
    assert not out.exists()


# --- faults, alarms and safing in the demo's summary ------------------------------------------


def test_demo_refuses_a_fault_it_cannot_read_or_the_robot_lacks_before_starting(
    tmp_path: Path,
) -> None:
    """spacecraft/faults.py's reasons, one line, status 2, nothing started or written."""
    out = tmp_path / "demo"
    for spec, words in (
        ("joint3-stuck", "fault 'joint3-stuck': needs NAME@T"),
        ("joint9-stuck@10", "the robot has 6 joints (joint1 to joint6), no joint9"),
    ):
        result = subprocess.run(
            [sys.executable, "-m", "hikoboshi", "demo", "--out", str(out), "--fault", spec],
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert result.returncode == 2, result.stderr
        assert result.stderr.startswith("error: ") and words in result.stderr
        assert len(result.stderr.strip().splitlines()) == 1
        assert not out.exists()


def test_fault_specs_are_checked_against_the_robot_flown() -> None:
    check_fault_specs(("joint6-drift@10,rate_degps=1", "wheel3-fail@5", "bump@1,nms=5"), None)
    check_fault_specs(("joint7-stuck@10",), ORIHIME)  # Orihime has seven joints
    for specs, robot, words in (
        (("joint7-stuck@10",), None, "no joint7"),
        (("wheel4-fail@1",), None, "no wheel4"),
        (("joint3-stuck@10", "attitude-bias@5,deg=200"), None, "within +-180"),
        (("joint8-stuck@10",), ORIHIME, "no joint8"),
    ):
        with pytest.raises(DemoError, match=re.escape(words)):
            check_fault_specs(specs, robot)


#: The spacecraft's start on the onboard clock (the truth log's ``start``), and the ground
#: instant at which the link's mapping read onboard 80 s, at 20x.
START_NS = 1_795_733_964_000_000_000
GROUND_AT_80_NS = 1_795_700_000_000_000_000
CLOCK = OnboardClock(START_NS, GROUND_AT_80_NS, START_NS + 80 * 10**9, 20.0, 0.05)


def _onboard(s: float) -> int:
    return START_NS + round(s * 1e9)


def _ground(s: float) -> int:
    """The ground instant at which the onboard clock read ``s`` s from the start."""
    return GROUND_AT_80_NS + round((s - 80.0) / 20.0 * 1e9)


def _alarm(
    quantity: str,
    channel: str,
    steps: list[tuple[str | None, float | None, float, float]],
    *,
    limit: float | None,
    unit: str,
    source: str = "limit",
) -> dict[str, Any]:
    """An alarm as ``GET /api/alarms`` gives it; ``steps``: (severity, frame s or None for
    the link's health, ground s, value)."""
    bands = [s for s in steps if s[0] is not None]
    worst = max(bands, key=lambda s: ("watch", "warning", "distress", "critical").index(s[0]))
    first = steps[0]
    return {
        "id": f"{quantity}-{channel}",
        "pass_id": "p",
        "quantity": quantity,
        "channel": channel,
        "label": quantity,
        "unit": unit,
        "direction": "high",
        "source": source,
        "severity": worst[0],
        "current_severity": steps[-1][0],
        "state": "triggered" if steps[-1][0] else "cleared",
        "acknowledged": False,
        "limit": limit,
        "trigger_value": first[3],
        "worst_value": max(s[3] for s in steps),
        "last_value": steps[-1][3],
        "count": len(bands),
        "raised_frame_seq": None if first[1] is None else round(first[1] * 10),
        "raised_generation_time_ns": None if first[1] is None else _onboard(first[1]),
        "raised_time_ns": _ground(first[2]),
        "timeline": [
            {
                "severity": severity,
                "generation_time_ns": None if frame_s is None else _onboard(frame_s),
                "time_ns": _ground(ground_s),
                "frame_seq": None if frame_s is None else round(frame_s * 10),
                "value": value,
            }
            for severity, frame_s, ground_s, value in steps
        ],
        "detail": None,
    }


#: A joint 3 stuck during the PTP: the ground's alarms (newest first, as REST lists them).
STUCK_ALARMS = [
    _alarm(
        "vehicle_safing",
        "",
        [("critical", 101.8, 104.9, 3.02)],
        limit=3.0,
        unit="deg",
        source="vehicle",
    ),
    _alarm(
        "joint_tracking_error_deg",
        "joint3",
        [
            ("watch", 99.3, 102.4, 2.05),
            ("warning", 100.5, 103.6, 2.55),
            ("critical", 101.8, 104.9, 3.02),
            (None, 101.9, 105.0, 0.1),
        ],
        limit=3.0,
        unit="deg",
    ),
    _alarm(
        "frames_behind",
        "",
        [("watch", None, 24.5, 212.0), (None, None, 110.8, 3.0)],
        limit=100.0,
        unit="frames",
    ),
]
TRIGGER = {
    "quantity": "joint_tracking_error_deg",
    "channel": "joint3",
    "value": 3.02,
    "limit": 3.0,
    "detail": "joint 3 at -0.820 deg, its servo target -3.840 deg",
}
STUCK_TRUTH = [
    {"event": "start", "onboard_time_ns": START_NS, "faults": ["joint3-stuck@90"]},
    {
        "event": "fault",
        "fault": "joint3-stuck",
        "spec": "joint3-stuck@90",
        "onboard_time_ns": _onboard(90.0),
        "onboard_s": 90.0,
    },
    {"event": "safing_entry", "onboard_time_ns": _onboard(101.8), "onboard_s": 101.8, **TRIGGER},
]
STUCK_EVENTS = [
    {"kind": "pass_state", "time_ns": _ground(20.0), "detail": {"from": "aos", "to": "running"}},
    {"kind": "command_stage", "time_ns": _ground(30.0), "detail": {}},
    {"kind": "pass_state", "time_ns": _ground(105.2), "detail": {"from": "running", "to": "safed"}},
    {
        "kind": "vehicle_safed",
        "time_ns": _ground(110.0),  # written behind the archive's queue
        "detail": {"since_time_ns": _onboard(101.8), "trigger": TRIGGER, "cancelled": 456},
    },
]


def _command(stage: str, at_s: float, reason: str | None = None) -> dict[str, Any]:
    executed = _onboard(at_s) if stage == "executed" else None
    return {
        "seq": round(at_s * 4),
        "stage": stage,
        "execute_time_ns": _onboard(at_s),
        "executed_at_ns": executed,
        "reject_reason": reason,
    }


def _safing(**changes: Any) -> dict[str, Any]:
    fields: dict[str, Any] = {
        "record": {"state": "safed", "state_reason": "the vehicle safed itself"},
        "link": {"vehicle_mode": "safe", "safing": {"state": "safe", "trigger": TRIGGER}},
        "alarms": STUCK_ALARMS,
        "events": STUCK_EVENTS,
        "truth": STUCK_TRUTH,
        "executed": [_command("executed", 100.0), _command("executed", 101.8)],
        "cancelled": [
            _command("cancelled", 102.0, "safing"),
            _command("cancelled", 102.25, "safing"),
            _command("cancelled", 150.0),
        ],
        "clock": CLOCK,
    }
    fields.update(changes)
    return safing_section(**fields)


def test_the_alarms_section_gives_each_bands_crossing_in_onboard_seconds() -> None:
    section = alarms_section(STUCK_ALARMS, CLOCK)
    assert (section["count"], section["above_watch"]) == (3, 2)
    assert section["by_severity"] == {"watch": 1, "critical": 2}
    # oldest raised first
    assert [a["quantity"] for a in section["items"]] == [
        "frames_behind",
        "joint_tracking_error_deg",
        "vehicle_safing",
    ]
    link, joint, vehicle = section["items"]
    assert joint["crossings"] == {"watch": 99.3, "warning": 100.5, "critical": 101.8}
    assert joint["raised_frame_s"] == 99.3  # the frame it was raised on
    assert joint["raised_ground_s"] == pytest.approx(102.4, abs=1e-3)  # 3.1 s later, ground
    assert (joint["severity"], joint["limit"], joint["worst_value"]) == ("critical", 3.0, 3.02)
    assert joint["timeline"][-1]["severity"] is None and joint["timeline"][-1]["frame_s"] == 101.9
    # the link's health has no frame: its band is crossed when the ground saw it
    assert link["raised_frame_s"] is None and link["crossings"] == {"watch": 24.5}
    assert vehicle["source"] == "vehicle" and vehicle["crossings"] == {"critical": 101.8}
    # without the truth log's start the demo cannot say onboard s
    blind = alarms_section(STUCK_ALARMS, OnboardClock())["items"][1]
    assert blind["raised_frame_s"] is None and blind["crossings"]["watch"] is None


def test_the_safing_section_tells_the_vehicles_safing_and_counts_commands_after_it() -> None:
    safing = _safing()
    assert safing["safed"] and safing["since_s"] == 101.8
    assert safing["trigger"] == TRIGGER and safing["cancelled_on_board"] == 456
    # heard when its alarm was raised on the report, not when the event was written
    assert safing["ground_heard_s"] == pytest.approx(104.9, abs=1e-3)
    assert safing["pass_ended_s"] == pytest.approx(105.2, abs=1e-3)
    assert [e["kind"] for e in safing["events"]] == ["pass_state", "vehicle_safed"]
    assert [f["spec"] for f in safing["truth_faults"]] == ["joint3-stuck@90"]
    assert [r["event"] for r in safing["truth_safing"]] == ["safing_entry"]
    # the command executed at the safing's own tick came before it
    assert safing["commands_executed_after_safing"] == 0
    assert safing["commands_cancelled_safing"] == 2
    late = [_command("executed", 101.8), _command("executed", 102.0)]
    assert _safing(executed=late)["commands_executed_after_safing"] == 1
    # without the event (a vehicle that safed after the pass ended), the link's last report
    report = {"state": "safe", "since_time_ns": _onboard(120.0), "trigger": TRIGGER, "cancelled": 3}
    later = _safing(events=[], alarms=[], link={"vehicle_mode": "safe", "safing": report})
    assert (later["since_s"], later["cancelled_on_board"]) == (120.0, 3)
    assert later["ground_heard_s"] is None


def test_a_nominal_pass_has_no_safing_and_no_count_after_it() -> None:
    nominal = _safing(
        record={"state": "complete", "state_reason": None},
        link={"vehicle_mode": "nominal", "safing": None},
        alarms=[],
        events=[],
        truth=STUCK_TRUTH[:1],
        executed=[],
        cancelled=[],
    )
    assert not nominal["safed"] and nominal["since_s"] is None
    assert nominal["commands_executed_after_safing"] is None
    assert nominal["truth_faults"] == [] and nominal["vehicle_mode"] == "nominal"


def _summary(state: str, faults: list[str], **changes: Any) -> dict[str, Any]:
    summary: dict[str, Any] = {
        "final_state": state,
        "state_reason": None,
        "faults": faults,
        "frames_missing": 0,
        "commands_outstanding": 0,
        "alarms": alarms_section(STUCK_ALARMS if faults else STUCK_ALARMS[2:], CLOCK),
        "safing": _safing(),
    }
    if not faults:
        summary["safing"] = _safing(
            link={"safing": None}, alarms=[], events=[], truth=STUCK_TRUTH[:1], executed=[]
        )
    summary.update(changes)
    return summary


def test_the_verdict_of_a_nominal_demo_is_complete_with_no_frame_missing() -> None:
    ok = verdict(_summary("complete", []))
    assert ok["ok"] and ok["problems"] == []
    assert ok["notes"][0] == "0 alarms above watch (1 in all)"
    assert "the vehicle never safed itself" in ok["notes"]
    loud = verdict(_summary("complete", [], alarms=alarms_section(STUCK_ALARMS, CLOCK)))
    assert loud["ok"]  # alarms are listed, as a nominal demo's status has always been
    assert loud["notes"][0] == (
        "2 alarms above watch: joint_tracking_error_deg joint3 critical (worst 3.02 deg, "
        "limit 3); vehicle_safing critical (worst 3.02 deg, limit 3)"
    )
    assert verdict(_summary("safed", []))["problems"] == ["the pass ended safed, not complete"]
    missing = verdict(_summary("complete", [], frames_missing=4))
    assert not missing["ok"] and missing["problems"] == ["frames missing: 4"]
    text = "degraded: 393 of 6190 commands expired"
    degraded = verdict(_summary("complete", [], outcome="degraded", outcome_text=text))
    assert degraded["problems"] == [f"the pass is {text}"]
    assert f"outcome {text}" in degraded["notes"]
    fine = "nominal: all 6190 commands executed at their tags"
    assert verdict(_summary("complete", [], outcome="nominal", outcome_text=fine))["ok"]


def test_the_verdict_of_a_fault_rehearsal_is_safed_or_complete_and_sound() -> None:
    safed = verdict(_summary("safed", ["joint3-stuck@90"]))
    assert safed["ok"], safed["problems"]
    assert "fault joint3-stuck@90 began at onboard 90.00 s" in safed["notes"]
    assert (
        "the vehicle safed itself at onboard 101.80 s (joint_tracking_error_deg joint3 3.02 "
        "beyond 3), dropping 456 commands; 0 executed after"
    ) in safed["notes"]
    assert verdict(_summary("complete", ["joint3-stuck@90"]))["ok"]  # e.g. a wheel alone
    for changes, problem in (
        ({"final_state": "aborted"}, "the pass ended aborted, neither safed nor complete"),
        ({"frames_missing": None}, "frames missing: None"),
        ({"commands_outstanding": 2}, "2 commands still outstanding"),
        (
            {"safing": _safing(executed=[_command("executed", 102.0)])},
            "1 commands executed after the vehicle safed",
        ),
        (
            {"faults": ["joint3-stuck@90", "bump@400"]},
            "never began (the truth log has no onset): bump@400",
        ),
    ):
        summary = _summary("safed", ["joint3-stuck@90"])
        summary.update(changes)
        result = verdict(summary)
        assert not result["ok"] and result["problems"] == [problem]


def test_the_truth_log_is_read_without_a_line_cut_short(tmp_path: Path) -> None:
    path = tmp_path / "truth.jsonl"
    path.write_text("".join(json.dumps(r) + "\n" for r in STUCK_TRUTH[:2]) + '{"event":"safing_en')
    assert read_truth_log(path) == STUCK_TRUTH[:2]
    assert read_truth_log(tmp_path / "none.jsonl") == []


def test_the_plans_segments_are_placed_on_the_onboard_clock() -> None:
    epoch_ns = _onboard(76.75)
    segments = [{"name": "ptp: A->B", "kind": "ptp", "t_start_s": 0.0, "t_end_s": 53.75}]
    (ptp,) = segments_section(segments, epoch_ns, CLOCK)
    assert (ptp["onboard_start_s"], ptp["onboard_end_s"]) == (76.75, 130.5)


def _rehearsal_script() -> Any:
    path = Path(__file__).resolve().parents[1] / "scripts" / "fault_rehearsal.py"
    spec = importlib.util.spec_from_file_location("fault_rehearsal", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_fault_rehearsal_collects_each_runs_key_numbers() -> None:
    """scripts/fault_rehearsal.py's parsing of a summary, on the fixtures above."""
    rehearsal = _rehearsal_script()
    assert rehearsal.spec_at("bump,nms=30,axis=y", 87.75) == "bump@87.75,nms=30,axis=y"
    assert parse_fault(rehearsal.spec_at("joint3-stuck", 90)).spec == "joint3-stuck@90"
    plan = [
        {"name": "ptp: A->B", "kind": "ptp", "t_start_s": 0.0, "t_end_s": 53.75},
        {"name": "ptp: settle", "kind": "settle", "t_start_s": 53.75, "t_end_s": 153.75},
    ]
    summary = _summary(
        "safed", ["joint3-stuck@90"], segments=segments_section(plan, _onboard(76.75), CLOCK)
    )
    summary["verdict"] = verdict(summary)
    row = rehearsal.row(summary, 0)
    assert row["fault"] == "joint3-stuck@90" and row["fault_s"] == 90.0
    assert row["ptp_s"] == [76.75, 130.5] and row["inside_ptp"] is True
    # the alarm of the safing's trigger, each band's crossing, when the ground raised it
    assert (row["alarm"], row["severity"]) == ("joint_tracking_error_deg joint3", "critical")
    assert row["crossings"] == {"watch": 99.3, "warning": 100.5, "critical": 101.8}
    assert (row["raised_frame_s"], row["raised_ground_s"]) == (99.3, pytest.approx(102.4))
    assert row["safed_s"] == 101.8 and row["commands_executed_after_safing"] == 0
    assert (row["final_state"], row["ok"], row["exit_status"]) == ("safed", True, 0)
    text = rehearsal.table([row])
    header, line = text.splitlines()
    assert header.split()[:3] == ["fault", "began", "(in"]
    for cell in ("joint3-stuck@90", "90.00 (yes)", "watch 99.30 warning 100.50 critical 101.80"):
        assert cell in line
    assert line.split()[-4:] == ["101.80", "0", "safed", "0"]
    # no safing (a failed wheel alone): the worst alarm raised on a frame tells the fault;
    # the link's health (no frame) does not
    quiet = dict(summary, safing=_safing(link={"safing": None}, events=[], alarms=[]))
    quiet["alarms"] = alarms_section(STUCK_ALARMS[1:], CLOCK)
    quiet["final_state"] = "complete"
    row = rehearsal.row(quiet)
    assert row["alarm"] == "joint_tracking_error_deg joint3" and row["safed_s"] is None
    assert row["commands_executed_after_safing"] is None
    early = dict(quiet, segments=segments_section(plan, _onboard(95.0), CLOCK))
    assert rehearsal.row(early)["inside_ptp"] is False
    assert "90.00 (NO)" in rehearsal.table([rehearsal.row(early)])


def test_the_demo_says_where_its_tokens_are_never_the_tokens(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Without ``--json`` the demo announces the console: with the tokens file (what the
    demo hands it, with the console's URL), which the run's logs may show."""
    from hikoboshi.demo_cli import _announce

    _announce("http://127.0.0.1:8000/", Path("out/demo/tokens"))
    printed = capsys.readouterr().err
    assert "out/demo/tokens" in printed and "http://127.0.0.1:8000/" in printed
