"""Recordings for the report, analysis and import tests, made once per session.

- ``short_recording`` (tests/server/conftest.py, made by tests/support/recordings.py): the
  cheap PTP plan (54 s, feedback attitude control) flown offline, with commands (stage
  times, one rejected), audit events and the meta of an aborted pass. Identification runs
  on it; the gravity-gradient resim cannot (no free drift).
- ``demo_recording`` (tests/conftest.py), its MCAP bytes, and its analyses computed once in
  memory (``demo_run``), the reference the stored ones must equal.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from server.services.analyses import AnalysisRun, compute_analyses
from telemetry.recording import PassRecording


@pytest.fixture(scope="session")
def demo_mcap(demo_mcap_file: Path) -> bytes:
    return demo_mcap_file.read_bytes()


@pytest.fixture(scope="session")
def demo_run(demo_recording: PassRecording) -> AnalysisRun:
    return compute_analyses(demo_recording)
