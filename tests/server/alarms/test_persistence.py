"""A limit's persistence (docs/alarms.md, "Persistence"): frames whose joint tracking error
flickers across the watch threshold, through the ground's own frame evaluator and alarm
book. With the robot's ``[limits] persistence = 3`` an excursion shorter than three frames
raises nothing and a flickering value raises one alarm; with 1 (the default) every crossing
raises or reopens."""

from __future__ import annotations

from dataclasses import replace

import pytest

from planner.description import default_robot
from planner.limits import QUANTITIES, Limits, Severity
from server.services.alarm_book import AlarmBook, Change, QuantityInfo
from server.services.alarm_monitor import observation
from telemetry.limits import FrameEvaluator, for_description
from tests.server.alarms.rig import TRACKING, below, frame, value_in

WATCH = value_in(TRACKING, Severity.WATCH)
WITHIN = below(TRACKING)


def _evaluator_and_book(persistence: int) -> tuple[FrameEvaluator, AlarmBook]:
    limits = Limits.from_table({"persistence": persistence})
    description = replace(default_robot(), limits=limits, collision=None)
    spec, bands = QUANTITIES[TRACKING], limits[TRACKING]
    info = QuantityInfo(spec.label, spec.unit, spec.direction, bands.threshold)
    book = AlarmBook("p", lambda q: info if q == TRACKING else None, persistence=persistence)
    return for_description(description), book


def _fly(persistence: int, errors: list[float], batch: int = 4) -> list[Change]:
    """Joint 3's error frame by frame, in messages of ``batch`` frames: every change, its
    alarm as it was then."""
    evaluator, book = _evaluator_and_book(persistence)
    frames = [frame(seq, {2: e}) for seq, e in enumerate(errors)]
    changes = []
    for k in range(0, len(frames), batch):
        readings = evaluator.evaluate(frames[k : k + batch])
        for c in book.observe([observation(r) for r in readings], now_ns=1_000 + k):
            changes.append(Change(c.alarm.model_copy(deep=True), c.kind))
    return changes


#: 30 frames flickering across the threshold (out on even frames, in on odd ones), then
#: two out and one in, then out for good from frame 33.
FLICKER = [WATCH if seq % 2 == 0 else WITHIN for seq in range(30)]
FLICKER += [WATCH, WATCH, WITHIN] + [WATCH] * 6


def test_a_flickering_value_raises_one_alarm_at_the_third_frame_out_in_a_row() -> None:
    changes = _fly(3, FLICKER)
    raised = [c for c in changes if c.kind in ("raised", "reopened")]
    assert len(raised) == 1
    alarm = raised[0].alarm
    assert alarm.raised_frame_seq == 35  # out at 33, 34, 35: raised on the third
    assert [e.frame_seq for e in alarm.timeline] == [35]
    assert [c.kind for c in changes if c.kind != "updated"] == ["raised"]
    last = changes[-1].alarm
    assert last.id == alarm.id and last.count == 4  # frames 35..38 in the band
    assert last.current_severity is Severity.WATCH and last.state == "triggered"


def test_without_persistence_every_crossing_raises_or_reopens() -> None:
    changes = _fly(1, FLICKER, batch=1)
    kinds = [c.kind for c in changes]
    # one alarm (not acknowledged: reopened), raised at frame 0, cleared and reopened at
    # each flicker: 14 reopens and 15 clears in the first 30 frames, 2 and 1 after
    assert (kinds.count("raised"), kinds.count("reopened"), kinds.count("cleared")) == (1, 16, 16)
    assert changes[0].alarm.raised_frame_seq == 0
    assert len(changes[-1].alarm.timeline) == 31 + 2  # every change of band


@pytest.mark.parametrize("batch", [1, 3, 50])
def test_the_count_runs_across_messages(batch: int) -> None:
    """Frames 0..1 out, 2 in, 3..5 out: raised at frame 5 however the frames come."""
    changes = _fly(3, [WATCH, WATCH, WITHIN, WATCH, WATCH, WATCH], batch)
    assert [(c.kind, c.alarm.raised_frame_seq) for c in changes] == [("raised", 5)]


def test_a_cleared_alarm_reopens_only_after_the_persistence_too() -> None:
    errors = [WATCH] * 3 + [WITHIN] + [WATCH, WITHIN] * 5 + [WATCH] * 3
    changes = _fly(3, errors, batch=1)
    assert [(c.kind, c.alarm.timeline[-1].frame_seq) for c in changes if c.kind != "updated"] == [
        ("raised", 2),
        ("cleared", 3),
        ("reopened", 16),
    ]
