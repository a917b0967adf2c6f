"""``hikoboshi robot init`` of the vendor arms, run once per test run and shared (by
tests/test_cli_robot_init.py and tests/planner/test_vendor_pinocchio.py, across xdist's
workers): the UR5 on the default cube with its URDF inside the description's folder
(named, not copied), the Panda on a 500 kg cube of 1.2 m with its URDF elsewhere."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from tests.support.vendor import vendor_urdf

if TYPE_CHECKING:
    from tests.support.made_once import MadeOnce


HIKOBOSHI = [sys.executable, "-m", "hikoboshi"]


HANDS = {"ur5": "tool0", "panda": "panda_hand_tcp"}


#: The cube each shared scaffold asks for (kg, m; the UR5's the defaults, not given).
CUBES = {"ur5": (300.0, 1.0), "panda": (500.0, 1.2)}


#: The shared UR5's URDF, inside the description's folder.
INSIDE = Path("urdf") / "ur5_robot.urdf"


GUARD_S = 600  # a guard against a hang, not a timing assertion


def run(*args: str) -> subprocess.CompletedProcess[str]:
    """``hikoboshi ARGS`` as a real subprocess, its output captured."""
    return subprocess.run([*HIKOBOSHI, *args], capture_output=True, text=True, timeout=GUARD_S)


@dataclass(frozen=True)
class Scaffolded:
    """One ``robot init --json`` run: the file it was asked to write and what it said."""

    out: Path
    urdf: Path  # the --urdf given
    returncode: int
    stdout: str
    stderr: str


def scaffold_once(made_once: MadeOnce, robot: str) -> Scaffolded:
    """``hikoboshi robot init`` (a real subprocess) of ``robot`` as :data:`CUBES` and
    :data:`INSIDE` say, once per test run; readers must not change its folder."""

    def make(folder: Path) -> None:
        args = ["robot", "init", "--hand", HANDS[robot], "--json"]
        if robot == "ur5":
            urdf = folder / "arm" / INSIDE
            urdf.parent.mkdir(parents=True)
            shutil.copyfile(vendor_urdf(robot), urdf)
        else:
            urdf = vendor_urdf(robot)
            mass, size = CUBES[robot]
            args += ["--base-mass", f"{mass:g}", "--base-size", f"{size:g}"]
        out = folder / "arm" / f"{robot}.toml"
        result = run(*args, "--urdf", str(urdf), "--out", str(out))
        said = {"out": str(out), "urdf": str(urdf), "returncode": result.returncode,
                "stdout": result.stdout, "stderr": result.stderr}  # fmt: skip
        (folder / "run.json").write_text(json.dumps(said))

    said = json.loads((made_once(f"robot-init-{robot}", make) / "run.json").read_text())
    return Scaffolded(
        out=Path(said["out"]),
        urdf=Path(said["urdf"]),
        returncode=said["returncode"],
        stdout=said["stdout"],
        stderr=said["stderr"],
    )
