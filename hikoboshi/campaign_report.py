"""The campaign demo's report (:mod:`hikoboshi.campaign_demo`): ``campaign.json``'s
document, from each pass's line and the spacecraft's truth log (the wheel momentum carried
across each gap, measured against the campaign's prediction; the commands sent outside a
window; the verdict), and ``campaign.md``, the same for people."""

from __future__ import annotations

import itertools
from datetime import datetime, timedelta
from typing import Any

from hikoboshi.campaign_passes import CampaignOptions, _PassSpec

__all__ = ["campaign_markdown"]


def _fmt(moment: datetime) -> str:
    from mission import format_utc

    return format_utc(moment)


def _utc(start: datetime, onboard_s: float) -> str:
    from mission import format_utc

    return format_utc(start + timedelta(seconds=onboard_s))


def _campaign_doc(
    options: CampaignOptions,
    mission: Any,
    results: list[dict[str, Any]],
    specs: list[_PassSpec],
    truth: list[dict[str, Any]],
    start_ns: int,
) -> dict[str, Any]:
    link = next((r for r in reversed(truth) if r.get("event") == "link"), None)
    outside = [r for r in truth if r.get("event") == "command_outside_window"]
    passes = []
    previous_end = -float("inf")
    for result in results:
        _, end_s = result.pop("_span_s")
        result["commands_sent_outside_window"] = sum(
            1 for r in outside if previous_end < r["onboard_s"] <= end_s
        )
        previous_end = end_s
        passes.append(result)
    gaps = []
    for before, after in itertools.pairwise(passes):
        h0, h1 = before["wheel_momentum_end_nms"], after["wheel_momentum_start_nms"]
        measured = (
            None if h0 is None or h1 is None else [b - a for a, b in zip(h0, h1, strict=True)]
        )
        predicted = after["predicted_gap_momentum_nms"]
        error = None
        if measured is not None and predicted is not None:
            error = sum((m - p) ** 2 for m, p in zip(measured, predicted, strict=True)) ** 0.5
        gaps.append(
            {
                "from_pass": before["pass"],
                "to_pass": after["pass"],
                "from_utc": before["end_utc"],
                "to_utc": after["epoch_utc"],
                "wheel_momentum_from_nms": h0,
                "wheel_momentum_to_nms": h1,
                "measured_nms": measured,
                "predicted_nms": predicted,
                "predicted_wheel_momentum_to_nms": after["predicted_wheel_momentum_start_nms"],
                "error_norm_nms": error,
            }
        )
    fast = [r for r in truth if r.get("event") == "gap"]
    problems = []
    for p in passes:
        if p["state"] != "complete":
            problems.append(f"pass {p['pass']} ended {p['state']}")
        if p["commands_executed_at_tag"] != p["commands_total"]:
            problems.append(
                f"pass {p['pass']}: {p['commands_executed_at_tag']} of {p['commands_total']} "
                "commands executed at their tag"
            )
        if p["commands_expired"]:
            problems.append(f"pass {p['pass']}: {p['commands_expired']} commands expired")
        if p["frames_missing"]:
            problems.append(f"pass {p['pass']}: {p['frames_missing']} frames missing")
        if p["analyses_error"]:
            problems.append(f"pass {p['pass']}: no report: {p['analyses_error']}")
    n_outside = None if link is None else link.get("commands_outside_window")
    n_delivered = None if link is None else link.get("commands_delivered_outside_window")
    if n_outside is None or n_delivered is None:
        problems.append("the spacecraft's link record is missing from the truth log")
    else:
        if n_outside:
            problems.append(f"{n_outside} commands were sent onto the relay outside a window")
        if n_delivered:
            problems.append(f"{n_delivered} commands reached the vehicle outside a window")
    return {
        "mission": mission.name,
        "mission_file": str(options.mission),
        "start_utc": options.start_utc.isoformat(),
        "speed": options.speed,
        "loss": options.loss,
        "fast_scale": options.fast_scale,
        "prediction": "mission.campaign" if any(s.gap_momentum_nms for s in specs) else None,
        "passes": passes,
        "gaps": gaps,
        "fast_gaps": [
            {
                "from_utc": _utc(options.start_utc, g["from_s"]),
                "to_utc": _utc(options.start_utc, g["to_s"]),
                "onboard_s": round(g["to_s"] - g["from_s"], 3),
                "wall_s": g["wall_s"],
            }
            for g in fast
        ],
        "commands_outside_window": n_outside,
        "commands_delivered_outside_window": n_delivered,
        "link": link,
        "truth_start_ns": start_ns,
        "verdict": {"ok": not problems, "problems": problems},
    }


def _v(vector: list[float] | None) -> str:
    return "-" if vector is None else "(" + ", ".join(f"{x:+.4f}" for x in vector) + ")"


def campaign_markdown(doc: dict[str, Any]) -> str:
    """The campaign report as Markdown (as the demo's summary, for people)."""
    lines = [
        f"# Campaign: {doc['mission']} from {doc['start_utc']}",
        "",
        f"Speed {doc['speed']:g}x in the windows, loss {doc['loss']:g}; the gaps flown fast.",
        "",
        "| pass | experiments | relay | AOS UTC | LOS UTC | state | at tag | expired | "
        "outside a window | frames missing |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for p in doc["passes"]:
        w = p["window"]
        lines.append(
            f"| {p['pass']} | {', '.join(p['experiments'])} | {w['relay']} | {w['aos_utc']} | "
            f"{w['los_utc']} | {p['state']} | {p['commands_executed_at_tag']} of "
            f"{p['commands_total']} | {p['commands_expired']} | "
            f"{p['commands_sent_outside_window']} | {p['frames_missing']} |"
        )
    lines += [
        "",
        "## Wheel momentum carried across the gaps (N m s, base frame)",
        "",
        "| gap | from UTC | to UTC | measured | predicted | error |",
        "|---|---|---|---|---|---|",
    ]
    for g in doc["gaps"]:
        err = "-" if g["error_norm_nms"] is None else f"{g['error_norm_nms']:.4f}"
        lines.append(
            f"| {g['from_pass']} -> {g['to_pass']} | {g['from_utc']} | {g['to_utc']} | "
            f"{_v(g['measured_nms'])} | {_v(g['predicted_nms'])} | {err} |"
        )
    lines += ["", "## Gaps flown fast (no window open)", ""]
    for g in doc["fast_gaps"]:
        lines.append(
            f"- {g['from_utc']} .. {g['to_utc']}: {g['onboard_s']:.0f} onboard s in "
            f"{g['wall_s']:.1f} wall s"
        )
    lines += [
        "",
        "Commands sent onto the relay outside a window: "
        f"{doc['commands_outside_window']}; received by the vehicle outside one: "
        f"{doc['commands_delivered_outside_window']}",
        "",
        "Verdict: " + ("ok" if doc["verdict"]["ok"] else "; ".join(doc["verdict"]["problems"])),
        "",
    ]
    return "\n".join(lines)
