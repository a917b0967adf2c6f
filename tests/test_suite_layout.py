"""The suite's own shape: what several test modules share lives in a helper module
(tests/support/, or a folder's harness such as tests/server/link/simulated.py), never in a
test module another imports (it would run that module's import-time work and tie two
modules' private names together)."""

from __future__ import annotations

import ast
from pathlib import Path

TESTS = Path(__file__).parent


def _test_modules_imported(source: str) -> list[str]:
    """The test modules (``tests.….test_*``) and conftests that ``source`` imports, at any
    depth (a conftest's fixtures reach its folder by pytest's scoping, its helpers belong in
    a helper module)."""
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom) and node.module:
            out.append(node.module)
        elif isinstance(node, ast.Import):
            out += [alias.name for alias in node.names]
    return [
        m
        for m in out
        if m.startswith("tests.") and m.rsplit(".", 1)[-1].startswith(("test_", "conftest"))
    ]


def test_no_module_of_the_suite_imports_a_test_module_or_a_conftest() -> None:
    files = sorted(TESTS.rglob("*.py"))
    assert len(files) > 200
    found = [
        f"{path.relative_to(TESTS)} imports {module}"
        for path in files
        for module in _test_modules_imported(path.read_text())
    ]
    assert found == []
    # and the check sees such an import where there is one, in a function too
    source = "from tests.a import b\ndef f():\n    from tests.x.test_y import z\n"
    assert _test_modules_imported(source) == ["tests.x.test_y"]
    assert _test_modules_imported("import tests.x.conftest") == ["tests.x.conftest"]
