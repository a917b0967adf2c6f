"""The alarm tests use the server's database fixtures (tests/server/conftest.py)."""
