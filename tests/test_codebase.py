"""The codebase keeps its own rules: lint, strict types on the pure packages, and imports
that point inward (planner <- telemetry <- spacecraft | server, STYLE.md)."""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from tests.support.processes import flocked

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent


def _run(*cmd: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300)


@pytest.mark.slow
def test_ruff_is_clean() -> None:
    result = _run(str(BIN / "ruff"), "check", "--no-cache", ".")
    assert result.returncode == 0, result.stdout + result.stderr


#: mypy's cache, shared by every checkout that runs on this environment (and held by one
#: run at a time): the installed libraries, half of a cold check's 40 s, are analysed once
#: per environment rather than once per fresh checkout. Nothing is skipped: mypy's
#: incremental mode re-checks each module whose content (hash) or dependencies changed.
MYPY_CACHE = Path(sys.prefix) / ".mypy_cache"


@pytest.mark.slow
def test_mypy_is_clean() -> None:
    MYPY_CACHE.mkdir(exist_ok=True)
    with flocked(MYPY_CACHE / "hikoboshi-tests.lock"):
        result = _run(
            str(BIN / "mypy"),
            "--cache-dir",
            str(MYPY_CACHE),
            "planner",
            "mission",
            "telemetry",
            "spacecraft",
            "server",
            "hikoboshi",
        )
    assert result.returncode == 0, result.stdout + result.stderr
    assert "Success: no issues found in" in result.stdout  # the packages were checked


@pytest.mark.slow
def test_import_contracts_hold() -> None:
    result = _run(str(BIN / "lint-imports"))
    assert result.returncode == 0, result.stdout + result.stderr
    # Every contract of pyproject.toml was checked and kept (none skipped or misnamed).
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]
    names = [contract["name"] for contract in config["contracts"]]
    assert len(names) >= 6
    for name in names:
        assert f"{name} KEPT" in result.stdout, name
    assert f"Contracts: {len(names)} kept, 0 broken" in result.stdout


#: The most lines a module of ours may hold (the brief's rule, issue 40): a room that outgrows
#: it is split, in the change that grows it, along a seam a reader would name.
MODULE_LINES_MAX = 500


def test_every_module_is_at_most_500_lines() -> None:
    packages = ("planner", "mission", "spacecraft", "telemetry", "server", "hikoboshi", "bench")
    modules = [path for package in packages for path in (ROOT / package).rglob("*.py")]
    modules += list((ROOT / "web" / "src").rglob("*.ts"))  # the console's own, not its deps
    sizes = {p.relative_to(ROOT).as_posix(): len(p.read_text().splitlines()) for p in modules}
    assert len(sizes) > 100  # the packages were found
    over = {name: n for name, n in sorted(sizes.items()) if n > MODULE_LINES_MAX}
    assert over == {}, f"over {MODULE_LINES_MAX} lines: {over}"
