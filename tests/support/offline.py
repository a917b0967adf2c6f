"""The command line in a fresh interpreter with every socket refused: what a command needs
with the network unreachable (imports, the time scale, the windows)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

_OFFLINE = """
import socket, sys


class NoNetwork(socket.socket):
    def __init__(self, *args, **kwargs):
        raise OSError("network unreachable")


socket.socket = NoNetwork
sys.argv = ["hikoboshi", *sys.argv[1:]]
from hikoboshi.cli import main

main()
"""


def run_offline(
    *args: str, cwd: Path | None = None, timeout_s: float = 300.0
) -> subprocess.CompletedProcess[str]:
    """``hikoboshi *args`` (in ``cwd``) with every socket refused; ``timeout_s`` a guard
    against a hang, not a timing assertion."""
    return subprocess.run(
        [sys.executable, "-c", _OFFLINE, *args],
        capture_output=True,
        text=True,
        timeout=timeout_s,
        cwd=cwd,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
