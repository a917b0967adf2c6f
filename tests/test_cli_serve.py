"""``hikoboshi serve``: the ground service as its own process."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import httpx

from tests.support.processes import free_port


def test_serve_answers_with_roles_from_the_environment(tmp_path: Path) -> None:
    port = free_port()
    env = {
        **os.environ,
        "HIKOBOSHI_DATA_DIR": str(tmp_path),
        "HIKOBOSHI_TOKENS": "v-tok=vera:viewer,o-tok=otto:operator",
    }
    env.pop("DATABASE_URL", None)
    proc = subprocess.Popen(
        [sys.executable, "-m", "hikoboshi", "serve", "--port", str(port)],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    try:
        base = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + 30.0
        while True:
            try:
                health = httpx.get(f"{base}/api/health", timeout=1.0)
                break
            except httpx.TransportError:
                assert time.monotonic() < deadline, "the server did not come up"
                assert proc.poll() is None, proc.stderr.read() if proc.stderr else ""
                time.sleep(0.2)
        assert health.json() == {"status": "ok", "command": "holder"}
        assert httpx.get(f"{base}/api/plans").status_code == 401
        viewer = {"Authorization": "Bearer v-tok"}
        assert httpx.get(f"{base}/api/plans", headers=viewer).status_code == 200
        assert (tmp_path / "hikoboshi.sqlite3").exists()
    finally:
        proc.terminate()
        proc.wait(timeout=20)
        for stream in (proc.stdout, proc.stderr):
            if stream is not None:
                stream.close()
