"""Importing the ground service reads no robot description: ``import server.app`` (and so
``server.services``, which imports ``planner.plan.ETS7_ROBOT_HASH``) opens nothing under
``examples/``. The shipped descriptions are read when a request needs them.

Checked in a fresh interpreter with an audit hook (``sys.addaudithook``) that records every
``open``, ``os.listdir``, ``os.scandir`` and ``glob.glob`` under ``examples/``; the same
interpreter then loads ETS-VII's description, so a hook that saw nothing would fail the test.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

_PROBE = """
import json, os, sys

examples = os.path.realpath(sys.argv[1])
seen = []


def hook(event, args):
    if event in ("open", "os.listdir", "os.scandir", "glob.glob") and args:
        target = args[0]
        if isinstance(target, (str, bytes, os.PathLike)):
            path = os.path.realpath(os.fsdecode(target))
            if path == examples or path.startswith(examples + os.sep):
                seen.append(path)


sys.addaudithook(hook)
import server.app  # noqa: E402,F401
import server.services  # noqa: E402,F401
from planner.plan import ETS7_ROBOT_HASH  # noqa: E402

at_import = list(seen)
from planner.description import ETS7_DESCRIPTION, load_robot  # noqa: E402

loaded = load_robot(ETS7_DESCRIPTION)
print(json.dumps({"at_import": at_import, "after_load": seen[len(at_import):],
                  "hash_matches": loaded.content_sha256 == ETS7_ROBOT_HASH}))
"""


def test_importing_the_server_opens_no_file_under_examples() -> None:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    result = subprocess.run(
        [sys.executable, "-c", _PROBE, str(ROOT / "examples")],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout.strip().splitlines()[-1])
    assert report["at_import"] == []
    # The hook sees reads: loading the description afterwards opens its TOML and URDF.
    opened = {Path(p).name for p in report["after_load"]}
    assert {"ets7.toml", "ets7.urdf"} <= opened
    assert report["hash_matches"]
