"""The rehearsal noise (``hikoboshi spacecraft --garbage``): its window and rate as the
command line gives them, and messages the ground's decoder refuses, one kind after the
other, the same for the same seed."""

from __future__ import annotations

import pytest

from spacecraft.garbage import KINDS, GarbageMaker
from spacecraft.link import Garbage, parse_garbage
from telemetry.wire import WireError, decode_spacecraft


def test_a_garbage_window_parses_and_bad_ones_are_refused_with_the_reason() -> None:
    assert parse_garbage("60:660:400") == Garbage(60.0, 660.0, 400.0)
    assert parse_garbage("60:660:400").contains(60.0)
    assert not parse_garbage("60:660:400").contains(660.0)
    for text, reason in (
        ("60:660", "is not START:END:RATE"),
        ("a:b:c", "is not START:END:RATE"),
        ("660:60:400", "must be greater than start_s"),
        ("60:660:0", "garbage rate"),
        ("60:660:nan", "garbage rate"),
    ):
        with pytest.raises(ValueError, match=reason):
            parse_garbage(text)


def test_every_message_is_refused_by_the_decoder_in_its_kind() -> None:
    maker = GarbageMaker(seed=4)
    codes = {
        "invalid_json": ("not_json", None),
        "unknown_type": ("unknown_type", "other"),
        "wrong_version": ("version", "telemetry"),
        "malformed_telemetry": ("invalid", "telemetry"),
    }
    for i in range(200):
        text = maker.next()
        with pytest.raises(WireError) as refused:
            decode_spacecraft(text)
        code, ref = codes[KINDS[i % 4]]
        assert refused.value.code == code, (KINDS[i % 4], str(refused.value))
        claimed = refused.value.ref_type
        assert (claimed if claimed in (None, "telemetry") else "other") == ref
    assert maker.made == dict.fromkeys(KINDS, 50)
    assert _replay(4) == _replay(4) and _replay(4) != _replay(5)


def _replay(seed: int) -> list[str]:
    maker = GarbageMaker(seed=seed)
    return [maker.next() for _ in range(8)]
