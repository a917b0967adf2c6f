"""The robots the ground plans for: a plan request names one (``"robot": NAME``), never a path.

The server knows the descriptions shipped under ``examples/robots/`` (a source checkout) and
those it was given at start (``hikoboshi serve --robot FILE``, ``HIKOBOSHI_ROBOTS``:
:attr:`server.settings.Settings.robot_files`; one of these shadows a shipped one of the same
name). A client chooses among them by the description's ``name``; it cannot make the server
read any other file. Resolving reads each TOML's ``name`` only (milliseconds, no URDF): the
planning worker loads and validates the description it is handed.
"""

from __future__ import annotations

import functools
import tomllib
from collections.abc import Sequence
from pathlib import Path

from planner.description import (
    EXAMPLES_DIR,
    MAX_FILE_BYTES,
    RobotDescription,
    default_robot,
    load_robot,
)
from planner.errors import PlannerError
from planner.meshes import MeshVisual
from planner.model import RobotModel
from planner.plan import ETS7_ROBOT_HASH, Plan
from planner.urdf import urdf_xml
from server.services.errors import ConflictError, InvalidRequestError, NotFoundError
from server.settings import Settings

__all__ = [
    "description_by_hash",
    "description_for_plan",
    "description_named",
    "known_robots",
    "mesh_file",
    "meshes_for_plan",
    "model_for_plan",
    "resolve_robot",
    "robot_descriptions",
    "robot_urdf",
    "urdf_for_plan",
]


def _name_of(path: Path) -> str | None:
    try:
        if path.stat().st_size > MAX_FILE_BYTES:
            return None
        with path.open("rb") as f:
            name = tomllib.load(f).get("name")
    except (OSError, tomllib.TOMLDecodeError):
        return None
    return name if isinstance(name, str) and name else None


def _files(robot_files: Sequence[Path | str]) -> list[Path]:
    shipped = sorted(EXAMPLES_DIR.glob("*/*.toml")) if EXAMPLES_DIR.is_dir() else []
    return [*shipped, *(Path(p) for p in robot_files)]


def known_robots(settings: Settings) -> dict[str, Path]:
    """Robot name -> its description file: the shipped ones, then the server's own."""
    found: dict[str, Path] = {}
    for path in _files(settings.robot_files):
        name = _name_of(path)
        if name is not None:
            found[name] = path.resolve()
    return found


def resolve_robot(settings: Settings, name: str | None) -> Path | None:
    """The description file of the robot a request names (None: ETS-VII as built in);
    the invalid request ``unknown_robot`` naming the known ones."""
    if name is None:
        return None
    robots = known_robots(settings)
    if name not in robots:
        raise InvalidRequestError(
            "unknown_robot",
            f"no robot named {name!r} on this server; it knows {sorted(robots)} (a server "
            "flies other descriptions given at its start: hikoboshi serve --robot FILE)",
        )
    return robots[name]


@functools.lru_cache(maxsize=16)
def _description(path: str, mtime_ns: int) -> RobotDescription | None:
    try:
        return load_robot(path)
    except PlannerError:
        return None


def _loaded(path: Path) -> RobotDescription | None:
    """The description in ``path``, loaded once per modification (None: it does not load)."""
    try:
        mtime_ns = path.stat().st_mtime_ns
    except OSError:
        return None
    return _description(str(path.resolve()), mtime_ns)


def robot_descriptions(settings: Settings) -> dict[str, RobotDescription]:
    """The known robots (:func:`known_robots`) whose descriptions load, by name; a file that
    no longer loads is left out (planning with it answers the loader's message)."""
    found: dict[str, RobotDescription] = {}
    for name, path in known_robots(settings).items():
        description = _loaded(path)
        if description is not None and description.name == name:
            found[name] = description
    return found


def description_named(settings: Settings, name: str) -> RobotDescription:
    """The known robot ``name``; ``NotFoundError`` ``unknown_robot`` naming the known ones."""
    robots = robot_descriptions(settings)
    if name not in robots:
        raise NotFoundError(
            "unknown_robot",
            f"no robot named {name!r} on this server; it knows {sorted(robots)} (a server "
            "flies other descriptions given at its start: hikoboshi serve --robot FILE)",
        )
    return robots[name]


def _by_hash(robot_files: Sequence[Path | str], robot_hash: str) -> RobotDescription | None:
    for path in _files(robot_files):
        description = _loaded(path)
        if description is not None and description.content_sha256 == robot_hash:
            return description
    return None


def description_by_hash(settings: Settings, robot_hash: str) -> RobotDescription:
    """The description whose ``content_sha256`` is ``robot_hash`` (a plan's ``robot_hash``:
    a shipped robot or one the server was given, whatever its name now);
    ``NotFoundError`` ``unknown_robot`` when the server has none."""
    found = _by_hash(settings.robot_files, robot_hash)
    if found is None:
        raise NotFoundError(
            "unknown_robot",
            f"no robot description with hash {robot_hash} on this server (it knows "
            f"{sorted(robot_descriptions(settings))}; a plan made for a robot given by file "
            "needs that file: hikoboshi serve --robot FILE)",
        )
    return found


def description_for_plan(plan: Plan, robot_files: Sequence[Path | str] = ()) -> RobotDescription:
    """The description of the robot ``plan`` was made for, found by its hash (ETS-VII's
    built in; another among the shipped descriptions and ``robot_files``);
    ``ConflictError`` ``robot_unknown`` when the server has none (the flight rules and the
    flown clearance need the robot's own collision geometry)."""
    if plan.robot_hash == ETS7_ROBOT_HASH:
        return default_robot()
    found = _by_hash(robot_files, plan.robot_hash)
    if found is None:
        raise ConflictError(
            "robot_unknown",
            f"the plan is for robot {plan.robot!r} (description {plan.robot_hash[:12]}), "
            "which this server has no description of: start it with hikoboshi serve --robot "
            "FILE",
        )
    return found


#: The frames the export names itself (planner.urdf): equipment may not take these names.
_EXPORT_FRAMES = frozenset({"base_link", "robot_base", "hand"})


def robot_urdf(description: RobotDescription, *, mesh_base: str | None = None) -> str:
    """The robot's URDF for viewers: the export of its model under its name (as ``hikoboshi
    model urdf --robot FILE`` prints it), with its base's display box and the keep-out
    equipment the flight rules check against, drawn (ETS-VII: exactly ``GET
    /api/model/urdf``). ``mesh_base``: the address the vendor's visual meshes are served
    under (``/api/robots/NAME/meshes/``; None: primitives only)."""
    box = description.base_box_size_m
    extra = {} if box is None else {"base_box_size_m": box}
    equipment = (
        ()
        if description.collision is None
        else tuple(
            b
            for b in description.collision.bodies
            if b.is_equipment
            and b.name != description.base_link
            # a vendor's own base mesh (its hull is not drawn; its visual mesh is), and never
            # under a name the export gives its own frames (a UR5's link is "base_link")
            and any(s.kind != "convex" for s in b.shapes)
            and b.name not in _EXPORT_FRAMES
        )
    )
    return urdf_xml(
        description.model,
        name=description.name,
        equipment=equipment,
        meshes=description.visual_meshes,
        mesh_uri=None if mesh_base is None else (lambda key: mesh_base + key),
        **extra,
    )


def mesh_file(description: RobotDescription, key: str) -> Path:
    """The file of the visual mesh ``key`` (``3/base.dae``) of ``description``: only the
    files its URDF names and loading found (no path is made from the request);
    ``NotFoundError`` ``unknown_mesh`` naming the robot's meshes otherwise."""
    path = description.mesh_files.get(key)
    if path is None or not path.is_file():
        known = sorted(description.mesh_files)
        raise NotFoundError(
            "unknown_mesh",
            f"robot {description.name!r} has no mesh {key!r}; its meshes: "
            + (", ".join(known) if known else "none (it is drawn from primitives)"),
        )
    return path


def urdf_for_plan(plan: Plan, robot_files: Sequence[Path | str] = ()) -> str | None:
    """The URDF of the robot ``plan`` was made for (:func:`robot_urdf`; None: ETS-VII's
    built-in model), found by hash as :func:`model_for_plan` finds its model
    (``ConflictError`` ``robot_unknown`` when the server has no description of it)."""
    if plan.robot_hash == ETS7_ROBOT_HASH:
        return None
    found = _by_hash(robot_files, plan.robot_hash)
    if found is None:
        model_for_plan(plan, robot_files)  # raises ConflictError robot_unknown
        return None
    return robot_urdf(found)


def meshes_for_plan(
    plan: Plan, robot_files: Sequence[Path | str] = ()
) -> tuple[tuple[MeshVisual, bytes], ...]:
    """The visual meshes of the robot ``plan`` was made for, each with its file's bytes (for
    the recording's ``/robot_meshes``); none for ETS-VII, a robot without meshes, or one the
    server has no description of (:func:`urdf_for_plan` says so first)."""
    if plan.robot_hash == ETS7_ROBOT_HASH:
        return ()
    found = _by_hash(robot_files, plan.robot_hash)
    if found is None:
        return ()
    data = {key: path.read_bytes() for key, path in found.mesh_files.items()}
    return tuple((mesh, data[mesh.key]) for mesh in found.visual_meshes)


@functools.lru_cache(maxsize=16)
def _hash_and_model(path: str, mtime_ns: int) -> tuple[str, RobotModel] | None:
    try:
        description = load_robot(path)
    except PlannerError:
        return None
    return description.content_sha256, description.model


def model_for_plan(plan: Plan, robot_files: Sequence[Path | str] = ()) -> RobotModel | None:
    """The model of the robot ``plan`` was made for (None: ETS-VII's built-in model), found
    by its description hash among the descriptions the server knows (shipped, and
    ``robot_files``); ``ConflictError`` ``robot_unknown`` when none has it (the post-pass
    work needs the robot's own model: its URDF, its joints)."""
    if plan.robot_hash == ETS7_ROBOT_HASH:
        return None
    for path in _files(robot_files):
        try:
            mtime_ns = path.stat().st_mtime_ns
        except OSError:
            continue
        found = _hash_and_model(str(path.resolve()), mtime_ns)
        if found is not None and found[0] == plan.robot_hash:
            return found[1]
    raise ConflictError(
        "robot_unknown",
        f"the pass's plan is for robot {plan.robot!r} (description {plan.robot_hash[:12]}), "
        "which this server has no description of: start it with hikoboshi serve --robot FILE",
    )
