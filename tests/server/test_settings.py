"""Settings from the environment, a ``.env`` file and a secrets directory
(``Settings.from_env``), and the table of docs/operations.md held to the model."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from server import settings as settings_module
from server.settings import ApiToken, Role, Settings, env_names

#: A value for every setting, none its default, as the environment writes it, and what it
#: must read as.
EVERY_SETTING: dict[str, tuple[str, object]] = {
    "data_dir": ("/srv/hikoboshi", Path("/srv/hikoboshi")),
    "database_url": ("postgresql://db/ground", "postgresql://db/ground"),
    "tokens": (
        "o-tok=otto:operator, v-tok=vera:viewer,s-tok=ets7:spacecraft",
        {
            "o-tok": ApiToken(name="otto", role=Role.OPERATOR),
            "v-tok": ApiToken(name="vera", role=Role.VIEWER),
            "s-tok": ApiToken(name="ets7", role=Role.SPACECRAFT),
        },
    ),
    "link_one_way_delay_s": ("2.5", 2.5),
    "uplink_margin_s": ("1.5", 1.5),
    "uplink_lead_window_s": ("90", 90.0),
    "uplink_start_lead_s": ("20", 20.0),
    "window_clock": ("vehicle", "vehicle"),
    "command_period_s": ("0.5", 0.5),
    "api_pool_size": ("5", 5),
    "api_pool_overflow": ("1", 1),
    "api_pool_timeout_s": ("2", 2.0),
    "api_statement_timeout_s": ("12", 12.0),
    "viewer_requests_max": ("7", 7),
    "viewer_queue": ("9", 9),
    "viewer_queue_wait_s": ("4", 4.0),
    "heavy_reads_per_token": ("3", 3),
    "operator_pool_size": ("4", 4),
    "operator_pool_overflow": ("3", 3),
    "console_db_threads": ("3", 3),
    "consoles_per_token": ("5", 5),
    "consoles_per_address": ("6", 6),
    "max_import_bytes": ("1000000", 1_000_000),
    "max_plan_document_bytes": ("3000000", 3_000_000),
    "max_import_uncompressed_bytes": ("8000000", 8_000_000),
    "import_spool_budget_bytes": ("2000000", 2_000_000),
    "worker_processes": ("3", 3),
    "worker_queue": ("16", 16),
    "plan_deadline_s": ("60", 60.0),
    "read_deadline_s": ("45", 45.0),
    "post_pass_deadline_s": ("300", 300.0),
    "artifact_cache_bytes": ("0", 0),
    "worker_memory_bytes": ("0", 0),
    "max_request_bytes": ("2048", 2048),
    "max_json_depth": ("8", 8),
    "auth_failure_limit": ("5", 5),
    "auth_failure_window_s": ("30", 30.0),
    "auth_tracked_addresses": ("100", 100),
    "trusted_proxies": (" 10.0.0.2, fd00::/8 ,", ("10.0.0.2", "fd00::/8")),
    "header_timeout_s": ("4", 4.0),
    "keep_alive_timeout_s": ("2", 2.0),
    "max_header_bytes": ("4096", 4096),
    "robot_files": (f"a.toml{os.pathsep}/x/b.toml", (Path("a.toml"), Path("/x/b.toml"))),
    "missions_dir": ("/srv/missions", Path("/srv/missions")),
    "limit_checking": ("off", False),
    "malformed_interval_s": ("2", 2.0),
    "malformed_replies_per_s": ("0", 0.0),
    "malformed_unusable_after": ("50", 50),
    "foxglove_port": ("8765", 8765),
    "foxglove_host": ("10.0.0.5", "10.0.0.5"),
    "command_lease": ("ets-vii-b", "ets-vii-b"),
    "ground_name": ("tsukuba-1", "tsukuba-1"),
    "lease_ttl_s": ("8", 8.0),
    "lease_renew_s": ("2", 2.0),
    "database_journal_max": ("5000", 5000),
    "nats_url": ("nats://10.0.0.7:4222", "nats://10.0.0.7:4222"),
    "nats_stream": ("ETS7_LIVE", "ETS7_LIVE"),
    "nats_max_age_s": ("3600", 3600.0),
    "nats_max_bytes": ("2097152", 2_097_152),
}


@pytest.fixture()
def clean_env(monkeypatch: pytest.MonkeyPatch) -> pytest.MonkeyPatch:
    for name in list(os.environ):
        if name.startswith("HIKOBOSHI_") or name == "DATABASE_URL":
            monkeypatch.delenv(name)
    monkeypatch.setenv("HIKOBOSHI_ENV_FILE", os.devnull)
    monkeypatch.setenv("HIKOBOSHI_SECRETS_DIR", os.devnull)
    return monkeypatch


def test_every_setting_is_listed_here() -> None:
    assert set(EVERY_SETTING) == set(Settings.model_fields)
    defaults = Settings()
    for name, (_, value) in EVERY_SETTING.items():
        assert getattr(defaults, name) != value, f"{name}: the test value is the default"


def test_every_setting_through_the_environment(clean_env: pytest.MonkeyPatch) -> None:
    for name, (text, _) in EVERY_SETTING.items():
        clean_env.setenv(env_names(name)[0], text)
    settings = Settings.from_env()
    for name, (_, value) in EVERY_SETTING.items():
        assert getattr(settings, name) == value, name


def test_older_variable_names_still_work(clean_env: pytest.MonkeyPatch) -> None:
    clean_env.setenv("DATABASE_URL", "sqlite:////tmp/x.db")
    clean_env.setenv("HIKOBOSHI_ROBOTS", "r.toml")
    clean_env.setenv("HIKOBOSHI_LIMIT_CHECKING", "0")
    settings = Settings.from_env()
    assert settings.database_url == "sqlite:////tmp/x.db"
    assert settings.robot_files == (Path("r.toml"),)
    assert settings.limit_checking is False


def test_empty_variables_are_the_defaults(clean_env: pytest.MonkeyPatch) -> None:
    for name in ("HIKOBOSHI_TOKENS", "DATABASE_URL", "HIKOBOSHI_WORKER_QUEUE"):
        clean_env.setenv(name, "")
    assert Settings.from_env() == Settings()


def test_direct_construction_reads_no_environment(clean_env: pytest.MonkeyPatch) -> None:
    clean_env.setenv("HIKOBOSHI_WORKER_QUEUE", "16")
    clean_env.setenv("HIKOBOSHI_TOKENS", "t=x:viewer")
    settings = Settings(data_dir=Path("d"))
    assert settings.worker_queue == 8 and settings.tokens == {}
    assert Settings.from_env().worker_queue == 16  # and from_env does


def test_env_file_and_secrets_dir_in_order(clean_env: pytest.MonkeyPatch, tmp_path: Path) -> None:
    env_file = tmp_path / "ground.env"
    env_file.write_text(
        "HIKOBOSHI_WORKER_QUEUE=11\nHIKOBOSHI_VIEWER_QUEUE=12\n"
        "HIKOBOSHI_SPACECRAFT_TOKEN=not-a-setting\n"
    )
    secrets = tmp_path / "secrets"
    secrets.mkdir()
    (secrets / "HIKOBOSHI_TOKENS").write_text("secret-tok=otto:operator\n")
    (secrets / "HIKOBOSHI_VIEWER_QUEUE").write_text("99")
    clean_env.setenv("HIKOBOSHI_ENV_FILE", str(env_file))
    clean_env.setenv("HIKOBOSHI_SECRETS_DIR", str(secrets))
    clean_env.setenv("HIKOBOSHI_WORKER_QUEUE", "13")
    settings = Settings.from_env()
    assert settings.worker_queue == 13  # the environment over the file
    assert settings.viewer_queue == 12  # the file over the secrets
    assert settings.tokens == {"secret-tok": ApiToken(name="otto", role=Role.OPERATOR)}


def test_a_named_file_that_is_missing_is_refused(
    clean_env: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    clean_env.setenv("HIKOBOSHI_ENV_FILE", str(tmp_path / "nowhere.env"))
    with pytest.raises(ValueError, match="HIKOBOSHI_ENV_FILE"):
        Settings.from_env()


@pytest.mark.parametrize(
    ("variable", "text", "reason"),
    [
        ("HIKOBOSHI_TOKENS", "t=otto:admin", "role 'admin' is not one of"),
        ("HIKOBOSHI_TOKENS", "justatoken", "token=name:role"),
        ("HIKOBOSHI_TRUSTED_PROXIES", "10.0.0.1,proxy.local", "not an IP address"),
        ("HIKOBOSHI_WORKER_PROCESSES", "0", "worker_processes"),
        ("HIKOBOSHI_LIMIT_CHECKING", "maybe", "limit_checking"),
    ],
)
def test_bad_values_are_refused_with_the_reason(
    clean_env: pytest.MonkeyPatch, variable: str, text: str, reason: str
) -> None:
    clean_env.setenv(variable, text)
    with pytest.raises(ValueError, match=reason):
        Settings.from_env()


def test_the_docs_table_is_the_model() -> None:
    text = settings_module.DOCS.read_text()
    assert settings_module.docs_with_table(text) == text, "run python -m server.settings"
    for name in Settings.model_fields:
        assert f"| `{name}` | `HIKOBOSHI_{name.upper()}`" in text
