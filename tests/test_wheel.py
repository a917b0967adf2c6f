"""The wheel: built from a copy of the source, installed into a fresh venv outside the
checkout, it asks for version ranges (the locks keep the pins), carries the console's build,
the shipped robots and missions (setup.py), and ``hikoboshi serve`` from it serves the
console and lists the robots."""

from __future__ import annotations

import importlib.util
import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import httpx
import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

from tests.support.processes import free_port, health_when_up

ROOT = Path(__file__).resolve().parents[1]
#: What the wheel is built from (the rest of the checkout is not needed for it).
SOURCES = [
    "pyproject.toml",
    "setup.py",
    "README.md",
    "LICENSE",
    "planner",
    "mission",
    "spacecraft",
    "telemetry",
    "server",
    "hikoboshi",
    "examples",
]
#: Files the wheel must carry, as package data, beside the code that reads them.
CARRIED = [
    "planner/description/robots/ets7/ets7.toml",
    "planner/description/robots/ets7/ets7.urdf",
    "planner/description/robots/orihime/orihime.toml",
    "mission/missions/ets7-1999.toml",
    "server/api/console/index.html",
    "server/storage/migrations/env.py",
]


def _run(*args: str | Path, env: dict[str, str] | None = None, cwd: Path | None = None) -> str:
    """The command's stdout; a failure shows its output."""
    result = subprocess.run(
        [str(a) for a in args], capture_output=True, text=True, env=env, cwd=cwd, timeout=300
    )  # the timeout: a guard, not a timing assertion
    assert result.returncode == 0, f"{args[:6]}...: {result.stdout[-2000:]}{result.stderr[-2000:]}"
    return result.stdout


def _source(tmp_path: Path) -> Path:
    """A copy of the sources, with the checkout's console build (or, where none is built, a
    stand-in page: what is tested is that the build travels, not the build itself)."""
    src = tmp_path / "src"
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    for name in SOURCES:
        if (ROOT / name).is_dir():
            shutil.copytree(ROOT / name, src / name, ignore=ignore)
        else:
            src.mkdir(exist_ok=True)
            shutil.copy2(ROOT / name, src / name)
    dist = ROOT / "web" / "dist"
    if (dist / "index.html").is_file():
        shutil.copytree(dist, src / "web" / "dist")
    else:
        (src / "web" / "dist").mkdir(parents=True)
        (src / "web" / "dist" / "index.html").write_text("<!doctype html><p>stand-in console")
    return src


def _locked(path: Path) -> dict[str, str]:
    """The lock file's pins, by canonical name."""
    pins = {}
    for line in path.read_text().splitlines():
        name, sep, version = line.partition("==")
        if sep and not line.startswith("#"):
            pins[canonicalize_name(name.split("[")[0].strip())] = version.split()[0].strip()
    return pins


def _requirements_are_ranges_that_hold_the_locks(wheel: Path) -> None:
    """The wheel asks its environment for ranges, never exact pins (they are the lock files'),
    and every lock's pin lies in its range (the main lock for the dependencies, the dev lock
    for the extras too)."""
    with zipfile.ZipFile(wheel) as archive:
        (metadata,) = [n for n in archive.namelist() if n.endswith(".dist-info/METADATA")]
        lines = archive.read(metadata).decode().splitlines()
    requires = [
        Requirement(line.partition(":")[2]) for line in lines if line.startswith("Requires-Dist:")
    ]
    assert len(requires) > 20
    main, dev = _locked(ROOT / "requirements.lock"), _locked(ROOT / "requirements-dev.lock")
    for requirement in requires:
        assert not any(s.operator in ("==", "===") for s in requirement.specifier), requirement
        assert requirement.specifier, f"{requirement} has no range"
        name = canonicalize_name(requirement.name)
        extra = requirement.marker is not None and "extra" in str(requirement.marker)
        pinned = dev[name] if extra else main[name]
        assert requirement.specifier.contains(pinned, prereleases=True), (requirement, pinned)


@pytest.mark.slow
def test_the_installed_wheel_serves_the_console_and_lists_the_robots(tmp_path: Path) -> None:
    src = _source(tmp_path)
    wheels = tmp_path / "wheels"
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "--no-input"]
    build = [*pip, "wheel", "--no-deps", "--no-build-isolation", "--no-index", "-w", wheels]
    # Without isolation, the venv's setuptools (65) builds, and needs the wheel package.
    assert importlib.util.find_spec("wheel") is not None, (
        "the wheel package is missing (requirements-dev.lock pins it): bash scripts/setup.sh --test"
    )
    _run(*build, src)
    (wheel,) = wheels.glob("hikoboshi-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    missing = [name for name in CARRIED if name not in names]
    assert not missing, f"the wheel lacks {missing}"
    assert any(name.endswith(".dist-info/LICENSE") for name in names), sorted(names)[-8:]
    assert not any(name.startswith(("examples/", "web/", "tests/")) for name in names)
    _requirements_are_ranges_that_hold_the_locks(wheel)

    # A fresh venv outside the checkout; the dependencies are this environment's, added as a
    # site directory after the venv's own (so the wheel's packages, not the checkout's
    # editable install, are the ones imported).
    venv = tmp_path / "venv"
    _run(sys.executable, "-m", "venv", "--without-pip", venv)
    purelib = _run(
        venv / "bin" / "python", "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"
    ).strip()
    deps = sysconfig.get_paths()["purelib"]
    (Path(purelib) / "zz_deps.pth").write_text(f"import site; site.addsitedir({deps!r})\n")
    install = [*pip, "--python", venv / "bin" / "python", "install", "--no-deps", "--no-index"]
    _run(*install, wheel)

    work = tmp_path / "run"
    work.mkdir()
    env = {**os.environ, "HIKOBOSHI_DATA_DIR": str(work / "data"), "HIKOBOSHI_TOKENS": "v=v:viewer"}
    for name in ("DATABASE_URL", "PYTHONPATH"):
        env.pop(name, None)
    where = _run(
        venv / "bin" / "python",
        "-c",
        "import planner.description as d, mission, server.api.web as w; "
        "print(d.EXAMPLES_DIR); print(mission.MISSIONS_DIR); print(w.DEFAULT_DIST)",
        env=env,
        cwd=work,
    ).split()
    assert [Path(p) for p in where] == [
        Path(purelib) / "planner" / "description" / "robots",
        Path(purelib) / "mission" / "missions",
        Path(purelib) / "server" / "api" / "console",
    ]

    port = free_port()
    proc = subprocess.Popen(
        [venv / "bin" / "hikoboshi", "serve", "--port", str(port)],
        cwd=work,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    try:
        base = f"http://127.0.0.1:{port}"
        health_when_up(proc, base, request_timeout_s=2.0)
        page = httpx.get(f"{base}/", timeout=10.0)
        assert page.status_code == 200
        assert page.content == (src / "web" / "dist" / "index.html").read_bytes()
        robots = httpx.get(
            f"{base}/api/robots", headers={"Authorization": "Bearer v"}, timeout=30.0
        )
        assert robots.status_code == 200, robots.text
        assert {"ets7", "orihime"} <= {r["name"] for r in robots.json()["data"]}
        # the shipped robots by name, from the wheel's own copy
        checked = _run(venv / "bin" / "hikoboshi", "robot", "check", "orihime", "--json", env=env)
        assert str(Path(purelib) / "planner" / "description" / "robots") in checked
    finally:
        proc.terminate()
        proc.wait(timeout=20)
        if proc.stderr is not None:
            proc.stderr.close()
