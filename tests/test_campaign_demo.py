"""The campaign demo end to end, short: two ptp passes in two consecutive TDRS-West windows
of 1999-09-30 (a 44-minute gap flown fast), at 10x with 10 % loss, through the code of
``hikoboshi demo --campaign`` (ground service, spacecraft process with ``--mission``).
10x, not the demo's 20x: the uplink's 120 s onboard lead is then 12 s of wall, not 6; at
20x, beside a busy core and a CPU-heavy test, the starved ground sent commands late and the
vehicle's refusals aborted the second pass.

Realtime (tests/conftest.py): it flies a vehicle in wall time. The README's command flies
the whole campaign at the default speed (docs/missions.md "The campaign demo").
"""

from __future__ import annotations

import json
from pathlib import Path

from hikoboshi.campaign_demo import CampaignOptions, run_campaign_demo
from mission import MISSIONS_DIR, parse_utc


def test_a_short_campaign_flies_every_command_at_its_tag_and_none_outside_a_window(
    tmp_path: Path,
) -> None:
    options = CampaignOptions(
        mission=MISSIONS_DIR / "ets7-1999.toml",
        start_utc=parse_utc("1999-09-30T00:20:00Z"),
        out=tmp_path / "campaign",
        speed=10.0,
        loss=0.1,
        port=0,
        seed=5,
        timeout_s=900.0,  # a hang guard, not a timing
        pass_experiments=(("ptp",), ("ptp",)),
        relay="TDRS-West",
    )
    doc = run_campaign_demo(options)
    assert doc == json.loads((tmp_path / "campaign" / "campaign.json").read_text())
    assert (tmp_path / "campaign" / "campaign.md").read_text().startswith("# Campaign")
    passes = doc["passes"]
    assert [p["window"]["relay"] for p in passes] == ["TDRS-West", "TDRS-West"]
    assert passes[0]["window"]["aos_utc"] < passes[1]["window"]["aos_utc"]
    for p in passes:
        assert p["state"] == "complete", p
        assert p["commands_total"] > 100
        assert p["commands_executed_at_tag"] == p["commands_total"]
        assert p["commands_expired"] == 0
        assert p["commands_sent_outside_window"] == 0
        assert p["frames_missing"] == 0
        # each pass flew inside its window's net time (UTC from the onboard clock)
        assert p["window"]["net_start_utc"] <= p["epoch_utc"]
        assert p["end_utc"] <= p["window"]["net_end_utc"]
        assert (tmp_path / "campaign" / f"pass-{p['pass']}" / "report.html").is_file()
    assert doc["commands_outside_window"] == 0
    assert doc["link"]["uplink"]["dropped_loss"] > 0  # the 10 % loss was there
    # the time before the first window and the gap between the two were flown fast, and
    # the vehicle carried its wheel momentum across: what the gap loaded is measured
    assert len(doc["fast_gaps"]) == 2
    (gap,) = doc["gaps"]
    assert gap["measured_nms"] is not None
    assert any(abs(x) > 1e-5 for x in gap["measured_nms"])
    assert doc["verdict"] == {"ok": True, "problems": []}
