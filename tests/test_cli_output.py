"""How the command line reads: help texts that keep their bracketed names and read as prose,
and output that is not hard-wrapped when it goes to a pipe or a file."""

from __future__ import annotations

import io
import os
import subprocess
import sys
from typing import Any

import pytest
import typer
from rich._emoji_codes import EMOJI
from rich.table import Table
from typer.testing import CliRunner

from hikoboshi.cli import app
from hikoboshi.output import PIPE_WIDTH, PipeAwareConsole

runner = CliRunner()
HIKOBOSHI = [sys.executable, "-m", "hikoboshi"]


def help_of(*command: str) -> str:
    result = runner.invoke(app, [*command, "--help"], env={"TERMINAL_WIDTH": "400"})
    assert result.exit_code == 0, result.output
    return result.output


@pytest.mark.parametrize(
    ("command", "bracketed"),
    [
        ((), "[experiments.NAME] tables"),  # plan, in the list of commands
        ((), "write the [acs] configuration"),  # calibrate, in the list of commands
        (("plan",), "its [experiments.NAME] tables as the defaults"),
        (("spacecraft",), "TOML file with [link], [uplink], [downlink] tables"),
        (("calibrate",), "The [acs] TOML file to write"),
        (("model", "limits"), "its [limits] over the built-in defaults"),
        (("serve",), "needs the hikoboshi[foxglove] extra"),
        (("demo",), "needs the hikoboshi[foxglove] extra"),
    ],
)
def test_help_keeps_bracketed_names(command: tuple[str, ...], bracketed: str) -> None:
    assert bracketed in help_of(*command)


def _command_paths() -> list[tuple[str, ...]]:
    """Every command and group of the command line, as the words that name it."""
    paths: list[tuple[str, ...]] = []

    def walk(command: Any, path: tuple[str, ...]) -> None:  # typer's own click's
        paths.append(path)
        if hasattr(command, "list_commands"):  # a group
            context = type(command).context_class(command)
            for name in command.list_commands(context):
                sub = command.get_command(context, name)
                if sub is not None and not sub.hidden:
                    walk(sub, (*path, name))

    walk(typer.main.get_command(app), ())
    return paths


def test_no_help_turns_a_colon_pair_into_an_emoji() -> None:
    """Rich reads ``:name:`` in a help text as an emoji code: ``START:END:RATE`` was shown
    ``START🔚RATE``. No command's help shows an emoji rich knows."""
    emoji = set(EMOJI.values())
    paths = _command_paths()
    assert len(paths) > 20 and ("spacecraft",) in paths and ("model", "limits") in paths
    for path in paths:
        text = help_of(*path)
        found = sorted(e for e in emoji if e in text)
        assert not found, (path, found)
    assert "START:END:RATE" in help_of("spacecraft")


def test_top_level_help_is_prose_without_rst() -> None:
    text = help_of()
    assert "``" not in text
    assert "ground system for the ETS-VII space robot" in text
    # a wrapped docstring is one paragraph: no line ends in the middle of "report.html and
    # the figures" at a width that holds the whole sentence
    assert "report.html and the figures" in text


def test_piped_output_is_not_hard_wrapped() -> None:
    console = PipeAwareConsole(file=io.StringIO(), _environ={})
    table = Table()
    table.add_column("name")
    table.add_column("value")
    table.add_row("x" * 150, "y" * 150)
    console.print(table)
    console.print("z" * 300)
    lines = console.file.getvalue().splitlines()  # type: ignore[attr-defined]
    assert console.width == PIPE_WIDTH
    assert any("x" * 150 in line and "y" * 150 in line for line in lines)
    assert "z" * 300 in lines


def test_a_terminal_still_wraps_at_its_width() -> None:
    console = PipeAwareConsole(file=io.StringIO(), force_terminal=True, _environ={"COLUMNS": "80"})
    console.print("z" * 300)
    assert console.width == 80
    assert max(len(line) for line in console.file.getvalue().splitlines()) == 80  # type: ignore[attr-defined]


def test_a_real_pipe_gets_whole_lines() -> None:
    # a real subprocess, stdout a pipe, no COLUMNS: each row of the quantities table (the
    # 6x6 Jacobian on one row) stays on one line; the 80-column default used to fold it
    env = {k: v for k, v in os.environ.items() if k not in ("COLUMNS", "LINES")}
    result = subprocess.run(
        [*HIKOBOSHI, "model", "quantities", "--joints-deg", "0,0,0,0,0,0"],
        capture_output=True,
        text=True,
        timeout=120,  # a guard against a hang, not a timing assertion
        env=env,
        stdin=subprocess.DEVNULL,
    )
    assert result.returncode == 0, result.stderr
    rows = [line for line in result.stdout.splitlines() if "generalized_jacobian" in line]
    assert len(rows) == 1 and len(rows[0]) > 200, result.stdout
    assert rows[0].count("[") == 7  # the whole 6x6 list on the row


def test_version_is_the_installed_package_s() -> None:
    import importlib.metadata

    result = runner.invoke(app, ["--version"])
    assert result.exit_code == 0, result.output
    assert result.output == f"hikoboshi {importlib.metadata.version('hikoboshi')}\n"
    assert "--version" in help_of()
