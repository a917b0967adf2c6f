"""Reading a description's files: size-limited bytes, and a TOML document from them.

The only module of the planner that opens a robot's files (``load_robot`` and
``load_vehicle_tables`` call it); everything after it works on bytes and parsed documents.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from planner.description.checks import Checker, InvalidRobotDescription

__all__ = [
    "ETS7_DESCRIPTION",
    "EXAMPLES_DIR",
    "MAX_FILE_BYTES",
    "read_limited",
    "read_mesh_points",
    "read_toml",
    "urdf_path_of",
]

#: Neither the TOML nor the URDF may be larger (checked by size before reading).
MAX_FILE_BYTES = 16 * 1024 * 1024
#: The shipped descriptions: in an installed wheel beside this module (``robots``, setup.py
#: copies them there), else the checkout's ``examples/robots`` (an editable install).
_PACKAGED = Path(__file__).resolve().parent / "robots"
EXAMPLES_DIR = (
    _PACKAGED if _PACKAGED.is_dir() else Path(__file__).resolve().parents[2] / "examples" / "robots"
)
ETS7_DESCRIPTION = EXAMPLES_DIR / "ets7" / "ets7.toml"


def read_limited(path: Path, what: str) -> bytes:
    """The file's bytes; refused by its size before reading anything when too large."""
    try:
        size = path.stat().st_size
    except FileNotFoundError:
        raise InvalidRobotDescription(path, what, "no such file") from None
    except OSError as exc:
        raise InvalidRobotDescription(path, what, f"cannot read it: {exc.strerror}") from None
    if not path.is_file():
        raise InvalidRobotDescription(path, what, "not a regular file")
    if size > MAX_FILE_BYTES:
        raise InvalidRobotDescription(
            path, what, f"the file is {size} bytes, over the {MAX_FILE_BYTES} byte limit"
        )
    try:
        with path.open("rb") as f:
            data = f.read(MAX_FILE_BYTES + 1)  # the file may have grown since stat
    except OSError as exc:
        raise InvalidRobotDescription(path, what, f"cannot read it: {exc.strerror}") from None
    if len(data) > MAX_FILE_BYTES:
        raise InvalidRobotDescription(path, what, f"over the {MAX_FILE_BYTES} byte limit")
    return data


def read_toml(toml_path: Path, what: str) -> tuple[Checker, dict[str, Any]]:
    """The TOML document at ``toml_path`` (a ``what``, size-limited) and its checker; a file
    that is not UTF-8 TOML raises one :class:`InvalidRobotDescription`."""
    c = Checker(toml_path)
    raw = read_limited(toml_path, what)
    try:
        return c, tomllib.loads(raw.decode("utf-8"))
    except UnicodeDecodeError:
        raise c.fail("document", "not UTF-8 text") from None
    except tomllib.TOMLDecodeError as exc:
        raise c.fail("document", f"not valid TOML: {exc}") from None


def urdf_path_of(c: Checker, toml_path: Path, urdf_name: str) -> Path:
    """The URDF a description names (``urdf_name``, relative), refused unless it stays inside
    the description's folder once symlinks are resolved."""
    urdf_path = toml_path.parent / urdf_name
    try:
        inside = urdf_path.resolve().is_relative_to(toml_path.parent.resolve())
    except (OSError, RuntimeError):  # a symlink loop
        inside = False
    if not inside:
        raise c.fail("urdf", f"{urdf_name!r} must stay inside the description's folder")
    return urdf_path


def read_mesh_points(urdf_path: Path, filename: str) -> NDArray[np.float64]:
    """The vertices of a mesh a URDF's ``<collision>`` names (a path relative to the URDF,
    or ``file://``; ``package://`` URIs need a ROS workspace and are refused with that
    reason), read by coal's mesh loader (assimp: STL, OBJ, DAE, ...), size-limited like the
    description's own files. The rules take the mesh as its convex hull."""
    import coal

    where = f"<collision> <mesh filename={filename!r}>"
    if filename.startswith("package://"):
        raise InvalidRobotDescription(
            urdf_path, where, "package:// needs a ROS workspace: give a path relative to the URDF"
        )
    name = filename.removeprefix("file://")
    path = Path(name) if Path(name).is_absolute() else urdf_path.parent / name
    read_limited(path, "mesh")  # the size limit and a clear error for a missing file
    try:
        mesh = coal.MeshLoader().load(str(path), np.ones(3))
        points = np.array([mesh.vertex(i) for i in range(mesh.num_vertices)], dtype=np.float64)
    except Exception as exc:  # assimp's own errors
        raise InvalidRobotDescription(urdf_path, where, f"cannot read the mesh: {exc}") from None
    if points.ndim != 2 or points.shape[0] < 4 or not np.all(np.isfinite(points)):
        raise InvalidRobotDescription(urdf_path, where, "the mesh has fewer than 4 finite points")
    return points
