"""What several test modules share: no module of the suite imports a test module or a
conftest (STYLE.md, "Tests"; tests/test_suite_layout.py)."""
