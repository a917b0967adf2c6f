"""Write docs/foxglove-layout.json: a Foxglove layout for a pass, live or recorded.

Built with foxglove-sdk's own layout types (``foxglove.layouts``, the foxglove extra), so
its keys are the ones Foxglove reads. Left, a 3D panel in the ``orbit`` frame: the robot from
``/robot_description`` posed by ``/tf``, and ``/scene`` (the plan's predicted hand path and
the commanded arm). Right, three plots (base attitude against the prediction, the joints'
tracking error, the wheels' momentum) above the log panel on ``/events``.

    .venv/bin/python scripts/foxglove_layout.py          # write it
    .venv/bin/python scripts/foxglove_layout.py --check  # exit 1 if the committed one differs
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import foxglove.layouts as fl

OUT = Path(__file__).resolve().parent.parent / "docs" / "foxglove-layout.json"


def _plot(title: str, series: list[tuple[str, str]]) -> fl.PlotPanel:
    return fl.PlotPanel(
        title=title,
        config=fl.PlotConfig(
            paths=[fl.PlotSeries(value=value, label=label) for value, label in series],
            show_legend=True,
        ),
    )


def layout() -> fl.Layout:
    three_d = fl.ThreeDeePanel(
        title="ETS-VII (orbit frame)",
        config=fl.ThreeDeeConfig(
            follow_tf="orbit",
            layers={
                "robot": fl.BaseRendererUrdfLayerSettings(
                    layer_id="foxglove.Urdf",
                    instance_id="robot",
                    label="robot (/robot_description)",
                    source_type="topic",
                    topic="/robot_description",
                ),
            },
            topics={
                "/scene": fl.BaseRendererSceneUpdateTopicSettings(visible=True),
            },
        ),
    )
    base = _plot(
        "Base attitude: measured and predicted (deg)",
        [
            ("/plot/base.roll_deg", "roll"),
            ("/plot/base.pitch_deg", "pitch"),
            ("/plot/base.yaw_deg", "yaw"),
            ("/plot/prediction.roll_deg", "roll predicted"),
            ("/plot/prediction.pitch_deg", "pitch predicted"),
            ("/plot/prediction.yaw_deg", "yaw predicted"),
        ],
    )
    joints = _plot(
        "Joint tracking error (deg)",
        [(f"/plot/joints.j{i}_error_deg", f"j{i}") for i in range(1, 7)],
    )
    wheels = _plot(
        "Wheel momentum (N m s, base frame)",
        [(f"/plot/wheels.momentum_{axis}_nms", axis) for axis in "xyz"],
    )
    events = fl.LogPanel(
        title="Audit events (/events)",
        config=fl.LogConfig(topic_to_render="/events", show_name=True, show_level=True),
    )
    right = fl.SplitContainer(
        direction="column",
        items=[
            fl.SplitItem(proportion=1.0, content=base),
            fl.SplitItem(proportion=1.0, content=joints),
            fl.SplitItem(proportion=1.0, content=wheels),
            fl.SplitItem(proportion=1.0, content=events),
        ],
    )
    return fl.Layout(
        content=fl.SplitContainer(
            direction="row",
            items=[
                fl.SplitItem(proportion=1.2, content=three_d),
                fl.SplitItem(proportion=1.0, content=right),
            ],
        )
    )


def text() -> str:
    return json.dumps(json.loads(layout().to_json()), indent=2, sort_keys=True) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="scripts/foxglove_layout.py")
    parser.add_argument("--check", action="store_true")
    args = parser.parse_args(argv)
    if args.check:
        if not OUT.exists() or OUT.read_text() != text():
            print(f"{OUT} is out of date: run scripts/foxglove_layout.py", file=sys.stderr)
            return 1
        return 0
    OUT.write_text(text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
