"""The vendor arms of the tests: the UR5 and the Franka Panda as the PyPI package
example-robot-data ships them (a dev dependency; nothing is downloaded at run time), and the
test descriptions in tests/planner/vendor/ that mount each on a 300 kg cube."""

from __future__ import annotations

import importlib.metadata
import re
import shutil
from pathlib import Path

#: The test descriptions of the vendor arms.
HERE = Path(__file__).parents[1] / "planner" / "vendor"
#: Each arm's URDF inside the package.
URDFS = {
    "panda": "panda_description/urdf/panda.urdf",
    "ur5": "ur_description/urdf/ur5_robot.urdf",
}
#: The package its URDFs name in ``package://`` paths.
PACKAGE = "example-robot-data"


def vendor_urdf(robot: str) -> Path:
    """The package's file (its installed path, found through the package's record)."""
    files = importlib.metadata.files("example-robot-data") or []
    (found,) = [f for f in files if str(f).endswith(URDFS[robot])]
    return Path(str(found.locate()))


def copy_robot(tmp_path: Path, robot: str) -> Path:
    """The test description of ``robot`` and the vendor's URDF beside it in ``tmp_path``."""
    target = tmp_path / robot
    target.mkdir()
    shutil.copyfile(vendor_urdf(robot), target / Path(URDFS[robot]).name)
    shutil.copyfile(HERE / f"{robot}.toml", target / f"{robot}.toml")
    return target / f"{robot}.toml"


def package_root(robot: str) -> Path:
    """The folder ``package://example-robot-data/`` means (share/example-robot-data)."""
    return vendor_urdf(robot).parents[3]


def meshed_robot(tmp_path: Path, robot: str, packages: str | None = None) -> Path:
    """The test description of ``robot`` with the URDF's own collision meshes instead of
    generated capsules: ``urdf_collision`` left at true, ``[packages]`` naming the package's
    folder, and the generated allowed contacts."""
    target = tmp_path / robot
    target.mkdir()
    shutil.copyfile(vendor_urdf(robot), target / Path(URDFS[robot]).name)
    text = (HERE / f"{robot}.toml").read_text()
    text = text.replace("urdf_collision = false  # its collision meshes are package:// files\n", "")
    text, count = re.subn(r"\[generated_collision\]\n(?:.+\n)*\n", "", text)
    assert count == 1
    folder = packages if packages is not None else str(package_root(robot))
    text += (
        f'\n[packages]\n"{PACKAGE}" = "{folder}"\n\n'
        "[flight_rules]\ngenerated_allowed_contact = true\n"
    )
    (target / f"{robot}.toml").write_text(text)
    return target / f"{robot}.toml"
