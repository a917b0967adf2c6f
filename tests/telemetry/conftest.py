"""The post-pass tests use ``demo_recording`` from tests/conftest.py (shared with the
server's report tests, so the pass is flown once per session)."""
