"""The short campaign the campaign demo's test flies (tests/test_campaign_demo.py) and
bench/bench_campaign.py flies again on the shipped geometry: its options and mission file."""

from __future__ import annotations

from pathlib import Path

from hikoboshi.campaign_passes import CampaignOptions
from mission import MISSIONS_DIR, parse_utc

#: The acquisition margin flown here (onboard s; the shipped mission's is 120 s).
AOS_MARGIN_S = 30.0
#: Where TDRS-East is moved to (east longitude; it flew at -41.0): its first window of the
#: day opens at 00:33:55, 4 minutes after the first pass's service ends, not at 01:04:50.
EAST_MOVED_DEG = -140.0


def short_campaign(
    where: Path, *, aos_margin_s: float = AOS_MARGIN_S, east_deg: float | None = EAST_MOVED_DEG
) -> CampaignOptions:
    """The short campaign's options, its mission file (the shipped one with ``aos_margin_s``
    and TDRS-East at ``east_deg``, None: where it flew) written under ``where``."""
    shipped = (MISSIONS_DIR / "ets7-1999.toml").read_text()
    assert shipped.count("aos_margin_s = 120.0") == shipped.count("longitude_deg = -41.0") == 1
    text = shipped.replace("aos_margin_s = 120.0", f"aos_margin_s = {aos_margin_s!r}")
    if east_deg is not None:
        text = text.replace("longitude_deg = -41.0", f"longitude_deg = {east_deg!r}")
    where.mkdir(parents=True, exist_ok=True)
    mission = where / "ets7-1999.toml"
    mission.write_text(text)
    return CampaignOptions(
        mission=mission,
        start_utc=parse_utc("1999-09-30T00:24:00Z"),
        out=where / "campaign",
        speed=10.0,
        loss=0.1,
        port=0,
        seed=5,
        timeout_s=900.0,  # a hang guard, not a timing
        pass_experiments=(("ptp",), ("ptp",)),
        pass_parameters={"ptp_settle_s": 20.0},
        service_tail_s=60.0,
    )
