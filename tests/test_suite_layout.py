"""The suite's own shape: what several test modules share lives in a helper module
(tests/support/, or a folder's harness such as tests/server/link/simulated.py), never in a
test module another imports (it would run that module's import-time work and tie two
modules' private names together)."""

from __future__ import annotations

import ast
from pathlib import Path

TESTS = Path(__file__).parent


def _imports(path: Path) -> list[str]:
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module:
            out.append(node.module)
        elif isinstance(node, ast.Import):
            out += [alias.name for alias in node.names]
    return out


def test_no_module_of_the_suite_imports_a_test_module() -> None:
    files = sorted(TESTS.rglob("*.py"))
    assert len(files) > 200
    found = [
        f"{path.relative_to(TESTS)} imports {module}"
        for path in files
        for module in _imports(path)
        if module.startswith("tests.") and module.rsplit(".", 1)[-1].startswith("test_")
    ]
    assert found == []
    # and the check sees such an import where there is one
    assert any(m.startswith("tests.support.") for m in _imports(TESTS / "test_cli_robot_init.py"))
