"""Builds the package; ``pyproject.toml`` holds everything but this one step.

The wheel carries, as package data, what a checkout keeps outside the packages: the shipped
robot descriptions (``examples/robots``), the missions (``examples/missions``) and the
operator console's build (``web/dist``, made by ``npm run build``; ``scripts/setup.sh``
runs it). Each is copied beside the code that reads it (``SHARED``); the code looks there
first and falls back to the checkout's folder, so an editable install and a checkout run as
before. A wheel built without ``web/dist`` says so and serves the "console not built" page.
"""

from __future__ import annotations

import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

ROOT = Path(__file__).resolve().parent
#: The checkout's folder -> where the installed package holds it (planner/description/
#: files.py, mission/file.py and server/api/web.py look there).
SHARED = {
    "examples/robots": "planner/description/robots",
    "examples/missions": "mission/missions",
    "web/dist": "server/api/console",
}


class BuildPyWithShared(build_py):
    """``build_py``, then the shared folders copied into the build (not for an editable
    install, which reads them from the checkout)."""

    def run(self) -> None:
        super().run()
        if getattr(self, "editable_mode", False):
            return
        for source_name, target_name in SHARED.items():
            source = ROOT / source_name
            if not source.is_dir():
                print(f"warning: {source_name} is missing: the wheel goes without it")
                continue
            target = Path(self.build_lib) / target_name
            shutil.rmtree(target, ignore_errors=True)
            shutil.copytree(source, target, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))


setup(cmdclass={"build_py": BuildPyWithShared})
