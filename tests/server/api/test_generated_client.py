"""A client generated from the OpenAPI document by an outside generator (openapi-python-client,
pinned in tools/openapi-client) calls every operation of the API against a running ground,
and each answer comes back as the document says: the status expected for the state the
test sets up, parsed into the documented model (a file as bytes or a File, a refusal as the problem
details' ``ErrorPublic`` with its code). The generator must read the document without a
warning: a response it drops is one its users would miss."""

from __future__ import annotations

import datetime
import importlib
import json
import pkgutil
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

from server.app import create_app
from server.settings import Settings
from server.storage.db import sqlite_url
from tests.server.link.harness import Ground, running_ground
from tests.server.storage.factories import make_plan
from tests.support.api import CHEAP_PTP, TOKENS
from tests.support.web import OPERATOR_TOKEN, stored_pass

pytestmark = pytest.mark.realtime  # serves the ground in wall time

ROOT = Path(__file__).resolve().parents[3]
TOOL = ROOT / "tools" / "openapi-client"
NOT_FOUND_ID = "00000000-0000-4000-8000-000000000000"


def _generate(out: Path) -> ModuleType:
    """The client generated from the service's document into ``out/hikoboshi_client``."""
    generator = TOOL / ".venv" / "bin" / "openapi-python-client"
    assert generator.is_file(), f"{generator} is missing: scripts/setup.sh --test makes it"
    document = out / "openapi.json"
    settings = Settings(data_dir=out, database_url=sqlite_url(out), tokens=TOKENS)
    document.write_text(json.dumps(create_app(settings).openapi()))
    result = subprocess.run(
        [
            str(generator),
            "generate",
            "--path",
            str(document),
            "--meta",
            "none",
            "--output-path",
            str(out / "hikoboshi_client"),
            "--config",
            str(TOOL / "config.yml"),
        ],
        capture_output=True,
        text=True,
        env={"PATH": f"{generator.parent}:/usr/bin:/bin"},  # its ruff formats the code
        timeout=300,  # a guard, not a timing assertion
    )
    assert result.returncode == 0, result.stdout + result.stderr
    assert "Warning" not in result.stdout, result.stdout  # nothing of the document dropped
    sys.path.insert(0, str(out))
    return importlib.import_module("hikoboshi_client")


@pytest.fixture(scope="module")
def client_package(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ModuleType]:
    out = tmp_path_factory.mktemp("generated")
    package = _generate(out)
    try:
        yield package
    finally:
        sys.path.remove(str(out))
        for name in [m for m in sys.modules if m.split(".")[0] == "hikoboshi_client"]:
            del sys.modules[name]


def _operations(package: ModuleType) -> dict[str, ModuleType]:
    """Every operation's module of the generated client, by operation id."""
    api = importlib.import_module(f"{package.__name__}.api")
    found = {}
    for tag in pkgutil.iter_modules(api.__path__):
        group = importlib.import_module(f"{api.__name__}.{tag.name}")
        for op in pkgutil.iter_modules(group.__path__):
            found[op.name] = importlib.import_module(f"{group.__name__}.{op.name}")
    return found


def _calls(m: Any, ids: dict[str, Any]) -> dict[str, tuple[Callable[[], dict[str, Any]], int, str]]:
    """Operation id -> (its arguments, the status expected, what it parses to: a model's
    name, ``File``, or a refusal's code)."""
    pass_id, plan_id = ids["pass_id"], ids["plan_id"]
    now = datetime.datetime.now(datetime.UTC)

    def body(model: str, doc: dict[str, Any]) -> Any:
        return getattr(m, model).from_dict(doc)

    return {
        "health": (lambda: {}, 200, "HealthResponseHealth"),
        "ready": (lambda: {}, 200, "ReadyPublic"),
        "command": (lambda: {}, 200, "CommandLeasePublic"),
        "link_status": (lambda: {}, 200, "LinkStatusResponseLinkStatus"),
        "list_missions": (lambda: {}, 200, "MissionsPublic"),
        "list_windows": (
            lambda: {
                "mission": "ets7-1999",
                "start": datetime.datetime(1999, 9, 30, tzinfo=datetime.UTC),
                "hours": 3.0,
            },
            200,
            "WindowsPublic",
        ),
        "list_robots": (lambda: {}, 200, "RobotsPublic"),
        "get_robot_urdf": (lambda: {"name": "ets7"}, 200, "bytes"),
        "get_robot_urdf_by_hash": (lambda: {"robot_hash": ids["robot_hash"]}, 200, "bytes"),
        "get_robot_mesh": (
            lambda: {"name": "ets7", "index": 0, "filename": "x.stl"},
            404,
            "unknown_mesh",
        ),
        "get_urdf": (lambda: {}, 200, "bytes"),
        "list_plans": (lambda: {}, 200, "PlansPublic"),
        "get_plan": (lambda: {"plan_id": plan_id}, 200, "PlanPublic"),
        "get_plan_document": (lambda: {"plan_id": plan_id}, 200, "GetPlanDocumentResponse200"),
        "create_plan": (lambda: {"body": body("PlanCreate", CHEAP_PTP)}, 201, "PlanPublic"),
        "validate_plan": (lambda: {"body": body("PlanCreate", CHEAP_PTP)}, 200, "PlanValidation"),
        "check_plan": (lambda: {"plan_id": plan_id}, 200, "PlanPublic"),
        "upload_plan_document": (
            lambda: {"body": body("UploadPlanDocumentBody", ids["document"]())},
            201,
            "PlanPublic",
        ),
        "list_passes": (lambda: {}, 200, "PassesPublic"),
        "get_pass": (lambda: {"pass_id": pass_id}, 200, "PassPublic"),
        "get_summary": (lambda: {"pass_id": pass_id}, 200, "PassSummaryPublic"),
        "list_commands": (lambda: {"pass_id": pass_id}, 200, "CommandsPublic"),
        "schedule_pass": (
            lambda: {
                "body": body(
                    "PassCreate",
                    {
                        "plan_id": plan_id,
                        "name": "generated-1",
                        "aos_time": now.isoformat(),
                        "los_time": (now + datetime.timedelta(hours=1)).isoformat(),
                        "relay": "TDRS-W",
                    },
                )
            },
            201,
            "PassPublic",
        ),
        "start_pass": (
            lambda: {"pass_id": pass_id, "body": body("StartRequest", {"confirm": "START no"})},
            422,
            "confirmation_mismatch",
        ),
        "abort_pass": (
            lambda: {"pass_id": pass_id, "body": body("AbortRequest", {"confirm": "ABORT no"})},
            422,
            "confirmation_mismatch",
        ),
        "safe_exit": (
            lambda: {"body": body("SafeExitRequest", {"confirm": "SAFE-EXIT no"})},
            503,
            "link_down",  # no vehicle connected: asked before the confirmation
        ),
        "list_events": (lambda: {"pass_id": pass_id}, 200, "EventsPublic"),
        "list_alarms": (lambda: {}, 200, "AlarmsPublic"),
        "acknowledge_alarm": (
            lambda: {"alarm_id": NOT_FOUND_ID, "body": body("AlarmAcknowledge", {})},
            404,
            "alarm_not_found",
        ),
        "get_telemetry": (lambda: {"pass_id": pass_id}, 200, "TelemetryPublic"),
        "quantity_across_passes": (
            lambda: {"field": "j1", "pass_id": [pass_id]},
            200,
            "QuantityAcrossPublic",
        ),
        "export_telemetry_csv": (lambda: {"pass_id": pass_id}, 200, "bytes"),
        "export_telemetry_parquet": (lambda: {"pass_id": pass_id}, 200, "File"),
        "download_recording": (lambda: {"pass_id": pass_id}, 409, "pass_not_flown"),
        "import_recording": (
            lambda: {"body": m.File(payload=b"not an mcap", file_name="x.mcap")},
            422,
            "invalid_recording",
        ),
        "list_analyses": (lambda: {"pass_id": pass_id}, 200, "AnalysesPublic"),
        "run_analyses": (lambda: {"pass_id": pass_id}, 409, "pass_not_flown"),
        "get_analysis": (
            lambda: {"pass_id": pass_id, "kind": "pass_analysis"},
            404,
            "analysis_not_run",
        ),
        "get_report": (lambda: {"pass_id": pass_id}, 404, "analysis_not_run"),
        "get_report_html": (lambda: {"pass_id": pass_id}, 404, "analysis_not_run"),
        "get_figure": (
            lambda: {"pass_id": pass_id, "name": "fig8_reactionless"},
            404,
            "figure_not_found",
        ),
    }


def test_a_generated_client_calls_every_operation(
    client_package: ModuleType, tmp_path: Path
) -> None:
    operations = _operations(client_package)
    models = importlib.import_module(f"{client_package.__name__}.models")
    types = importlib.import_module(f"{client_package.__name__}.types")
    namespace = type("M", (), {**vars(models), "File": types.File})
    with running_ground(sqlite_url(tmp_path)) as ground:
        ids = _stored(ground)
        calls = _calls(namespace, ids)
        assert set(calls) == set(operations)  # every operation, and none we made up
        wrong = {}
        with client_package.AuthenticatedClient(
            base_url=ground.url, token=OPERATOR_TOKEN, timeout=120.0
        ) as client:  # its connections closed with it
            for name, (arguments, status, parsed) in sorted(calls.items()):
                response = operations[name].sync_detailed(client=client, **arguments())
                got = type(response.parsed).__name__
                if got == "ErrorPublic":
                    got = response.parsed.code
                if (response.status_code, got) != (status, parsed):
                    wrong[name] = (response.status_code, got, response.content[:200])
        assert wrong == {}, "\n".join(f"{k}: {v[0]} {v[1]}" for k, v in wrong.items())


def _stored(ground: Ground) -> dict[str, Any]:
    """A stored plan (its id, robot hash) and a scheduled pass of it with frames; and how to
    fetch the document of the plan ``create_plan`` made (a planner's own, to upload)."""
    import httpx

    plan = make_plan()
    pass_id = stored_pass(ground, "generated", plan, 40)
    headers = {"Authorization": f"Bearer {OPERATOR_TOKEN}"}

    def get(path: str) -> Any:
        response = httpx.get(f"{ground.url}{path}", headers=headers, timeout=60.0)
        assert response.status_code == 200, response.text
        return response.json()

    plan_id = get(f"/api/passes/{pass_id}")["plan_id"]

    def planned_document() -> dict[str, Any]:
        [made] = [p for p in get("/api/plans")["data"] if p["id"] != plan_id]
        document: dict[str, Any] = get(f"/api/plans/{made['id']}/document")
        return document

    return {
        "pass_id": pass_id,
        "plan_id": plan_id,
        "robot_hash": get(f"/api/plans/{plan_id}/document")["robot_hash"],
        "document": planned_document,
    }
