"""docs/foxglove-layout.json: the committed file is the script's output, and every panel
reads a topic (and field) that the recording and the live view publish."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from telemetry.mcap import TOPIC_EVENT_LOG, TOPIC_ROBOT_DESCRIPTION
from telemetry.mcap._plots import frame_plot_messages, prediction_plot_messages
from telemetry.recording import frames_to_arrays
from tests.server.storage.factories import make_frames, make_plan

ROOT = Path(__file__).resolve().parents[2]
LAYOUT = ROOT / "docs" / "foxglove-layout.json"


def _walk(node: Any) -> list[dict[str, Any]]:
    """Every panel of the layout."""
    if isinstance(node, dict):
        if node.get("type") == "panel":
            return [node]
        return [p for value in node.values() for p in _walk(value)]
    if isinstance(node, list):
        return [p for item in node for p in _walk(item)]
    return []


def test_the_committed_layout_is_the_scripts() -> None:
    pytest.importorskip("foxglove.layouts", reason="the foxglove extra")
    result = subprocess.run(
        [sys.executable, "scripts/foxglove_layout.py", "--check"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=False,
    )
    assert result.returncode == 0, result.stderr


def test_every_panel_reads_what_is_published() -> None:
    panels = _walk(json.loads(LAYOUT.read_text()))
    assert sorted(p["panelType"] for p in panels) == ["Log", "Plot", "Plot", "Plot", "ThreeDee"]
    plan = make_plan(5)
    arrays = frames_to_arrays(make_frames(range(3)))
    schemas = {
        topic: set(schema["properties"])
        for topic, (schema, _, _) in frame_plot_messages(arrays, np.zeros(3)).items()
    }
    schemas["/plot/prediction"] = set(prediction_plot_messages(plan, 0)[0]["properties"])
    paths = [s["value"] for p in panels if p["panelType"] == "Plot" for s in p["config"]["paths"]]
    assert len(paths) >= 12
    for path in paths:
        topic, _, field = path.partition(".")
        assert field in schemas[topic], path
    [three_d] = [p for p in panels if p["panelType"] == "ThreeDee"]
    assert three_d["config"]["followTf"] == "orbit"
    [urdf] = three_d["config"]["layers"].values()
    assert urdf["topic"] == TOPIC_ROBOT_DESCRIPTION
    [log] = [p for p in panels if p["panelType"] == "Log"]
    assert log["config"]["topicToRender"] == TOPIC_EVENT_LOG
