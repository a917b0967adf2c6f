"""The campaign demo's upload path, without a flight: the campaign planner's pass documents
(``hikoboshi demo --campaign`` uploads them; tests/test_campaign_demo.py flies given
experiments the ground plans instead) sent by the demo's own
:class:`hikoboshi.campaign_demo.StoredPlans` to a running ground, which predicts and checks
each again and stores it with its commands as planned.

Two PTP passes of the short campaign's mission (tests/support/campaign.py), the second
starting where the first left the vehicle: its wheels carry the first pass's momentum and
what the gap loaded, and both predictions hold the gravity-gradient torque, so the ground's
prediction is made from a carried start on the campaign's orbit."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from hikoboshi.campaign_demo import StoredPlans
from hikoboshi.campaign_passes import _campaign
from hikoboshi.demo_harness import _Api
from planner.reprediction import PREDICTION_TOLERANCE
from server.storage.db import sqlite_url
from tests.server.link.harness import running_ground
from tests.support.campaign import short_campaign


def _unplanned(experiments: tuple[str, ...]) -> float:
    raise AssertionError(f"the campaign planner plans its own passes, not {experiments}")


def test_the_campaigns_pass_documents_are_uploaded_and_stored_as_planned(
    tmp_path: Path,
) -> None:
    options = dataclasses.replace(
        short_campaign(tmp_path), pass_experiments=None, assignment=(("ptp",), ("ptp",))
    )
    specs = _campaign(options, _unplanned)
    assert [s.experiments for s in specs] == [("ptp",), ("ptp",)]
    sent = [json.loads(s.document or "null") for s in specs]
    assert sent[0]["parameters"]["gravity_gradient_radius_m"] > 6.4e6
    assert any(abs(h) > 1e-6 for h in sent[1]["prediction"]["wheel_momentum_nms"][0])

    with running_ground(sqlite_url(tmp_path / "ground")) as ground:
        api = _Api(ground.url, "o-token")
        plans = StoredPlans(api)
        stored = [plans.of(s) for s in specs]
        assert [plans.of(s)["id"] for s in specs] == [p["id"] for p in stored]  # once each
        assert api.call("GET", "/api/plans")["count"] == 2
        for plan, document in zip(stored, sent, strict=True):
            assert plan["flight_rules"]["passed"] is True, plan["flight_rules"]
            kept = json.loads(api.raw("GET", f"/api/plans/{plan['id']}/document"))
            for part in ("commands", "acs_commands", "parameters", "robot_hash"):
                assert kept[part] == document[part], part
            # the ground's prediction, the campaign's to the tolerance (here 1e-22: the
            # carried start's base rate, made again, differs in its last bits)
            for column, values in document["prediction"].items():
                gap = np.abs(np.array(kept["prediction"][column]) - np.array(values))
                assert gap.max() <= PREDICTION_TOLERANCE, column
            assert plan["duration_s"] == document["commands"][-1]["t_s"]
