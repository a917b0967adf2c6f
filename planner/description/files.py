"""Reading a description's files: size-limited bytes, and a TOML document from them.

The only module of the planner that opens a robot's files (``load_robot`` and
``load_vehicle_tables`` call it); everything after it works on bytes and parsed documents.
"""

from __future__ import annotations

import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from planner.description.checks import Checker, InvalidRobotDescription

__all__ = [
    "ETS7_DESCRIPTION",
    "EXAMPLES_DIR",
    "MAX_FILE_BYTES",
    "MAX_MESHES_BYTES",
    "MAX_MESH_POINTS",
    "mesh_path",
    "packages_from",
    "read_limited",
    "read_limited_size",
    "read_mesh_points",
    "read_toml",
    "shipped_robots",
    "urdf_path_of",
]

#: Neither the TOML nor the URDF may be larger (checked by size before reading).
MAX_FILE_BYTES = 16 * 1024 * 1024
#: Every mesh a URDF names (visual and collision), added up, may be no larger: the server
#: hands them to each console that draws the robot (our choice: the 19 files example-robot-
#: data's panda.urdf names are 10.6 MB, the 14 of ur5_robot.urdf 6.9 MB; summed by st_size).
MAX_MESHES_BYTES = 64 * 1024 * 1024
#: A collision mesh may have no more points (its convex hull is built at every load).
MAX_MESH_POINTS = 200_000
#: The shipped descriptions: in an installed wheel beside this module (``robots``, setup.py
#: copies them there), else the checkout's ``examples/robots`` (an editable install).
_PACKAGED = Path(__file__).resolve().parent / "robots"
EXAMPLES_DIR = (
    _PACKAGED if _PACKAGED.is_dir() else Path(__file__).resolve().parents[2] / "examples" / "robots"
)
ETS7_DESCRIPTION = EXAMPLES_DIR / "ets7" / "ets7.toml"


def shipped_robots() -> dict[str, Path]:
    """The shipped descriptions by name (``ets7``, ``orihime``: each its folder's
    ``NAME/NAME.toml`` under :data:`EXAMPLES_DIR`), from a checkout and a wheel alike."""
    if not EXAMPLES_DIR.is_dir():
        return {}
    return {
        path.parent.name: path
        for path in sorted(EXAMPLES_DIR.glob("*/*.toml"))
        if path.stem == path.parent.name
    }


def read_limited_size(path: Path, what: str) -> int:
    """The size of a regular file within :data:`MAX_FILE_BYTES`; refused otherwise (nothing
    is read)."""
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
    return size


def read_limited(path: Path, what: str) -> bytes:
    """The file's bytes; refused by its size before reading anything when too large."""
    read_limited_size(path, what)
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


def packages_from(c: Checker, toml_path: Path, value: object) -> dict[str, Path]:
    """``[packages]``: where each ``package://NAME/`` a URDF's meshes name lives (a folder,
    relative to the description's or absolute), as ROS's package path would say; the folder
    must exist."""
    out: dict[str, Path] = {}
    for name, folder in c.table("[packages]", value).items():
        where = f"[packages] {name}"
        text = c.text(where, folder)
        path = Path(text) if Path(text).is_absolute() else toml_path.parent / text
        if not path.is_dir():
            raise c.fail(where, f"{text!r} is not a folder")
        out[name] = path.resolve()
    return out


def mesh_path(
    urdf_path: Path, filename: str, packages: Mapping[str, Path], where: str
) -> Path | None:
    """The file a URDF's ``<mesh filename>`` names: a path relative to the URDF, a
    ``file://`` path, or ``package://NAME/...`` inside the folder ``[packages]`` gives NAME
    (None: no folder is given for NAME). A package path that leaves its folder is refused."""
    if filename.startswith("package://"):
        name, _, rest = filename.removeprefix("package://").partition("/")
        folder = packages.get(name)
        if folder is None:
            return None
        path = (folder / rest).resolve()
        if not rest or not path.is_relative_to(folder):
            raise InvalidRobotDescription(
                urdf_path, where, f"leaves the folder of package {name!r} ({folder})"
            )
        return path
    name = filename.removeprefix("file://")
    return Path(name) if Path(name).is_absolute() else urdf_path.parent / name


def read_mesh_points(
    urdf_path: Path, filename: str, packages: Mapping[str, Path] | None = None
) -> NDArray[np.float64]:
    """The vertices of a mesh a URDF's ``<collision>`` names (:func:`mesh_path`; a
    ``package://`` URI needs its folder in ``[packages]``), read by coal's mesh loader
    (assimp: STL, OBJ, DAE, ...), size-limited like the description's own files and to
    :data:`MAX_MESH_POINTS` points. The rules take the mesh as its convex hull."""
    import coal

    where = f"<collision> <mesh filename={filename!r}>"
    path = mesh_path(urdf_path, filename, packages or {}, where)
    if path is None:
        package = filename.removeprefix("package://").partition("/")[0]
        raise InvalidRobotDescription(
            urdf_path,
            where,
            f"package:// needs a ROS workspace: name the folder of package {package!r} in the "
            "description's [packages], or give a path relative to the URDF",
        )
    read_limited(path, "mesh")  # the size limit and a clear error for a missing file
    try:
        mesh = coal.MeshLoader().load(str(path), np.ones(3))
        count = int(mesh.num_vertices)
        if count > MAX_MESH_POINTS:
            raise InvalidRobotDescription(
                urdf_path,
                where,
                f"the mesh has {count} points, over the {MAX_MESH_POINTS} point limit of a "
                "collision mesh: give a simpler one (its convex hull is what the rules use)",
            )
        points = np.array([mesh.vertex(i) for i in range(count)], dtype=np.float64)
    except InvalidRobotDescription:
        raise
    except Exception as exc:  # assimp's own errors
        raise InvalidRobotDescription(urdf_path, where, f"cannot read the mesh: {exc}") from None
    if points.ndim != 2 or points.shape[0] < 4 or not np.all(np.isfinite(points)):
        raise InvalidRobotDescription(urdf_path, where, "the mesh has fewer than 4 finite points")
    return points
