"""The command line starts without the planner's heavy libraries: each command group imports
them when one of its commands runs (or ``plan --help`` lists the experiments' parameters),
so that ``hikoboshi --help``, and every process the tests and the ground start, does not
pay for SciPy's optimisers and MuJoCo (most of a second) it may never use. A structural
check (what was imported), not a timing."""

from __future__ import annotations

import subprocess
import sys

#: Imported by no command line start-up (each is a package: its submodules count too).
HEAVY = ("scipy", "mujoco", "numpy", "planner.description")


def imported_modules(*args: str) -> tuple[subprocess.CompletedProcess[str], set[str]]:
    """Run ``python -X importtime ARGS``; the names of every module it imported."""
    result = subprocess.run(
        [sys.executable, "-X", "importtime", *args], capture_output=True, text=True, timeout=120
    )
    names = {
        line.rsplit("|", 1)[1].strip()
        for line in result.stderr.splitlines()
        if line.startswith("import time:") and "|" in line
    }
    names.discard("imported package")  # the header line
    return result, names


def heavy_among(names: set[str]) -> set[str]:
    return {n for n in names if any(n == h or n.startswith(h + ".") for h in HEAVY)}


def test_the_top_level_help_imports_no_heavy_library() -> None:
    result, names = imported_modules("-m", "hikoboshi", "--help")
    assert result.returncode == 0, result.stderr[-2000:]
    # Every group was imported and listed (so the check below looked at all of them, and
    # the parse finds what was imported; ``plan --help``, which lists the experiments'
    # parameters, does import the planner: tests/test_cli_plan.py checks that help).
    assert {"hikoboshi.planning_cli", "hikoboshi.robot_cli", "hikoboshi.model_cli"} <= names
    for command in ("plan", "robot", "model", "demo", "serve", "spacecraft", "calibrate"):
        assert f" {command} " in result.stdout
    assert heavy_among(names) == set()


def test_robot_init_shows_the_scaffold_defaults_without_the_description_package() -> None:
    result, names = imported_modules("-m", "hikoboshi", "robot", "init", "--help")
    assert result.returncode == 0, result.stderr[-2000:]
    assert "300.0" in result.stdout and "1.0" in result.stdout
    assert heavy_among(names) == set()
