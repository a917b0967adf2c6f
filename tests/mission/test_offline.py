"""Windows are computed with the network unreachable and nothing downloaded: skyfield's
builtin time scale, no ephemeris file. Every socket the process tries to open raises."""

from __future__ import annotations

import os
import socket
from datetime import UTC, datetime
from pathlib import Path

import pytest

from mission import MISSIONS_DIR, compute_windows, load_mission
from mission import windows as windows_module


class _NoNetwork(socket.socket):
    def __init__(self, *args: object, **kwargs: object) -> None:
        raise OSError("network unreachable (test_offline)")


def test_windows_need_no_network_and_write_no_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(socket, "socket", _NoNetwork)
    monkeypatch.chdir(tmp_path)  # skyfield's default loader would download here
    windows_module._timescale.cache_clear()  # the time scale is built again, offline
    try:
        with pytest.raises(OSError, match="network unreachable"):
            socket.create_connection(("192.0.2.1", 80), timeout=1)  # the patch holds
        found = compute_windows(
            load_mission(MISSIONS_DIR / "ets7-1999.toml"),
            datetime(1999, 9, 30, tzinfo=UTC),
            24.0,
        )
    finally:
        windows_module._timescale.cache_clear()
    assert len(found) >= 28
    assert os.listdir(tmp_path) == []
