"""``hikoboshi spacecraft`` takes its token from --token, --token-file, or the environment
(HIKOBOSHI_SPACECRAFT_TOKEN, HIKOBOSHI_SPACECRAFT_TOKEN_FILE), and refuses to start
without one."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from hikoboshi.cli import app

GROUND = ["spacecraft", "--ground", "ws://127.0.0.1:9/api/link"]


@pytest.fixture()
def flown(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """The token each SpacecraftProcess was built with (it runs no link)."""
    tokens: list[str] = []

    class Recorder:
        store = type("Store", (), {"unacked": 0})()
        connections = 0
        garbage_sent = 0

        def __init__(self, config: Any) -> None:
            tokens.append(config.token)

        async def run(self, stop: Any) -> None:
            return None

    monkeypatch.setattr("spacecraft.process.SpacecraftProcess", Recorder)
    for name in ("HIKOBOSHI_SPACECRAFT_TOKEN", "HIKOBOSHI_SPACECRAFT_TOKEN_FILE"):
        monkeypatch.delenv(name, raising=False)
    return tokens


def test_token_from_the_environment(flown: list[str]) -> None:
    result = CliRunner().invoke(app, GROUND, env={"HIKOBOSHI_SPACECRAFT_TOKEN": "env-tok"})
    assert result.exit_code == 0, result.output
    assert flown == ["env-tok"]


def test_token_from_a_file(flown: list[str], tmp_path: Path) -> None:
    secret = tmp_path / "token"
    secret.write_text("file-tok\n")
    result = CliRunner().invoke(app, [*GROUND, "--token-file", str(secret)])
    assert result.exit_code == 0, result.output
    result = CliRunner().invoke(app, GROUND, env={"HIKOBOSHI_SPACECRAFT_TOKEN_FILE": str(secret)})
    assert result.exit_code == 0, result.output
    assert flown == ["file-tok", "file-tok"]


@pytest.mark.parametrize(
    ("args", "reason"),
    [
        ([], "no spacecraft token"),
        (["--token-file", "/nonexistent/token"], "--token-file /nonexistent/token"),
    ],
)
def test_no_token_is_refused(flown: list[str], args: list[str], reason: str) -> None:
    result = CliRunner().invoke(app, [*GROUND, *args])
    assert result.exit_code == 2
    assert reason in result.output
    assert flown == []


def test_an_empty_token_file_is_refused(flown: list[str], tmp_path: Path) -> None:
    empty = tmp_path / "token"
    empty.write_text("\n")
    result = CliRunner().invoke(app, [*GROUND, "--token-file", str(empty)])
    assert result.exit_code == 2 and "is empty" in result.output
