"""``hikoboshi serve``: the ground service as its own process."""

from __future__ import annotations

import subprocess
from pathlib import Path

import httpx

from tests.support.processes import free_port, health_when_up, serve_command, serve_env


def test_serve_answers_with_roles_from_the_environment(tmp_path: Path) -> None:
    port = free_port()
    env = serve_env(tmp_path, "v-tok=vera:viewer,o-tok=otto:operator")
    proc = subprocess.Popen(
        serve_command(port), env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    try:
        base = f"http://127.0.0.1:{port}"
        health = health_when_up(proc, base, guard_s=30.0)
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
