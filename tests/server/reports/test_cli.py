"""``hikoboshi report`` and ``hikoboshi mcap export|import`` against the configured database
(``DATABASE_URL``: SQLite and PostgreSQL), and ``report`` of an .mcap file. The short
recording is imported and reported once per backend (``reported``), the tests that read its
report and its analyses share it."""

from __future__ import annotations

import io
import json
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from sqlalchemy.engine import make_url
from typer.testing import CliRunner

from hikoboshi.cli import app
from telemetry.mcap import read_mcap
from telemetry.recording import PassRecording

runner = CliRunner()


@pytest.fixture()
def env(database_url: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.setenv("DATABASE_URL", database_url)
    monkeypatch.setenv("HIKOBOSHI_DATA_DIR", str(tmp_path / "data"))
    return tmp_path


def run(*args: str) -> str:
    result = runner.invoke(app, list(args))
    assert result.exit_code == 0, (result.output, result.exception)
    return result.output


@dataclass(frozen=True)
class Reported:
    """The short recording imported by the command line and reported: its analyses run."""

    env: Path
    database_url: str
    import_output: str
    pass_id: str
    report_output: str


@pytest.fixture(scope="module")
def reported(
    module_database_url: str, tmp_path_factory: pytest.TempPathFactory, short_mcap: bytes
) -> Iterator[Reported]:
    """Once per module and backend: the analyses are the expensive part of a report."""
    env = tmp_path_factory.mktemp("reported")
    with pytest.MonkeyPatch.context() as monkeypatch:
        monkeypatch.setenv("DATABASE_URL", module_database_url)
        monkeypatch.setenv("HIKOBOSHI_DATA_DIR", str(env / "data"))
        source = env / "short.mcap"
        source.write_bytes(short_mcap)
        out = run("mcap", "import", str(source))
        match = re.search(r"imported pass ([0-9a-f-]{36}) ", out)
        assert match, out
        pass_id = match.group(1)
        report_output = run("report", pass_id, "--out", str(env / "report"))
        yield Reported(env, module_database_url, out, pass_id, report_output)


@pytest.fixture()
def reported_env(reported: Reported, monkeypatch: pytest.MonkeyPatch) -> Reported:
    """The command line pointed at ``reported``'s database."""
    monkeypatch.setenv("DATABASE_URL", reported.database_url)
    monkeypatch.setenv("HIKOBOSHI_DATA_DIR", str(reported.env / "data"))
    return reported


@pytest.fixture(scope="module")
def file_report(tmp_path_factory: pytest.TempPathFactory, short_mcap: bytes) -> Path:
    """``report`` of the .mcap file: no database, so once for the module."""
    out = tmp_path_factory.mktemp("file_report")
    source = out / "short.mcap"
    source.write_bytes(short_mcap)
    run("report", str(source), "--out", str(out / "from-file"))
    return out / "from-file"


def test_import_report_and_export_a_stored_pass(
    reported_env: Reported, short_recording: PassRecording
) -> None:
    env, pass_id, out = reported_env.env, reported_env.pass_id, reported_env.report_output
    imported = rf"imported pass {pass_id} .*: 571 frames, 12 commands, 2 events"
    assert re.search(imported, reported_env.import_output), reported_env.import_output
    assert "gravity_gradient_resim: failed (InsufficientData: no free-drift segment" in out
    report = json.loads((env / "report" / "report.json").read_text())
    assert report["pass_id"] == pass_id and report["imported"] is True
    assert [a["status"] for a in report["analyses"]] == ["ok", "ok", "failed", "ok"]
    page = (env / "report" / "report.html").read_text()
    for name in report["figures"]:
        assert f'src="{name}.png"' in page
        assert (env / "report" / f"{name}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    run("mcap", "export", pass_id, "--out", str(env / "out" / "again.mcap"))
    again = read_mcap(io.BytesIO((env / "out" / "again.mcap").read_bytes()))
    assert again.name == short_recording.name
    assert again.frames.joints_rad.tobytes() == short_recording.frames.joints_rad.tobytes()


def test_report_of_a_file_matches_the_report_of_the_stored_pass(
    reported: Reported, file_report: Path
) -> None:
    from_file = json.loads((file_report / "report.json").read_text())
    from_db = json.loads((reported.env / "report" / "report.json").read_text())
    assert from_file["pass_id"] is None and from_file["imported"] is False
    assert from_file["tables"] == from_db["tables"] and from_file["tables"]


@pytest.mark.parametrize(
    ("args", "reason"),
    [
        (("report", "no-such-pass", "--out", "x"), "not found"),
        (("report", "missing.mcap", "--out", "x"), "No such file"),
        (
            ("mcap", "export", "00000000-0000-4000-8000-000000000000", "--out", "x.mcap"),
            "not found",
        ),
        (("mcap", "import", "missing.mcap"), "No such file"),
    ],
)
def test_failures_are_one_line_and_status_2(
    env: Path, args: tuple[str, ...], reason: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(env)
    result = runner.invoke(app, list(args))
    assert result.exit_code == 2
    assert reason in result.output and result.output.startswith("error: ")


def test_importing_a_file_that_is_not_a_recording_fails_with_the_reason(env: Path) -> None:
    bad = env / "bad.mcap"
    bad.write_bytes(b"hello")
    result = runner.invoke(app, ["mcap", "import", str(bad)])
    assert result.exit_code == 2 and "not an MCAP file" in result.output


def test_import_prints_the_id_alone_on_stdout_and_json_on_request(
    env: Path, short_mcap: bytes
) -> None:
    source = env / "short.mcap"
    source.write_bytes(short_mcap)
    result = runner.invoke(app, ["mcap", "import", str(source)])
    assert result.exit_code == 0, result.output
    # stdout is the id and nothing else (PASS=$(hikoboshi mcap import FILE)); the sentence
    # for a person goes to stderr
    assert re.fullmatch(r"[0-9a-f-]{36}\n", result.stdout), result.stdout
    pass_id = result.stdout.strip()
    assert f"imported pass {pass_id} " in result.stderr

    result = runner.invoke(app, ["mcap", "import", str(source), "--json"])
    assert result.exit_code == 0, result.output
    doc = json.loads(result.stdout)
    assert doc["id"] != pass_id and re.fullmatch(r"[0-9a-f-]{36}", doc["id"])
    assert (doc["frames"], doc["commands"], doc["events"]) == (571, 12, 2)
    assert doc["state"] == "aborted" and doc["name"]  # as the recording says


def test_report_and_export_print_json_on_request(reported_env: Reported, tmp_path: Path) -> None:
    """On the pass ``reported`` analysed: its stored analyses are reported."""
    env, pass_id = tmp_path, reported_env.pass_id
    result = runner.invoke(app, ["report", pass_id, "--out", str(env / "r"), "--json"])
    assert result.exit_code == 0, result.output
    doc = json.loads(result.stdout)
    assert doc["pass_id"] == pass_id
    assert doc["report_html"] == str(env / "r" / "report.html")
    assert [a["status"] for a in doc["analyses"]] == ["ok", "ok", "failed", "ok"]
    assert doc["analyses"][2]["error"].startswith("InsufficientData")
    assert all(Path(f).read_bytes()[:4] == b"\x89PNG" for f in doc["figures"]) and doc["figures"]

    out = env / "again.mcap"
    result = runner.invoke(app, ["mcap", "export", pass_id, "--out", str(out), "--json"])
    assert result.exit_code == 0, result.output
    doc = json.loads(result.stdout)
    assert doc == {
        "pass_id": pass_id,
        "name": read_mcap(out).name,
        "path": str(out),
        "bytes": out.stat().st_size,
    }


def test_export_telemetry_as_csv_and_parquet(env: Path, short_mcap: bytes) -> None:
    import csv

    from arro3.io import read_parquet

    source = env / "short.mcap"
    source.write_bytes(short_mcap)
    pass_id = runner.invoke(app, ["mcap", "import", str(source)]).stdout.strip()

    result = runner.invoke(
        app, ["export", "telemetry", pass_id, "--out", str(env / "t.csv"), "--json"]
    )
    assert result.exit_code == 0, result.output
    doc = json.loads(result.stdout)
    assert doc == {
        "pass_id": pass_id,
        "path": str(env / "t.csv"),
        "format": "csv",
        "rows": 571,
        "bytes": (env / "t.csv").stat().st_size,
    }
    with (env / "t.csv").open(newline="") as file:
        lines = list(csv.reader(file))
    header, rows = lines[0], lines[1:]
    assert header[2] == "j1 [rad]" and len(rows) == 571

    run("export", "telemetry", pass_id, "--out", str(env / "t.parquet"))
    table = read_parquet(str(env / "t.parquet")).read_all()
    assert table.num_rows == 571
    # the same numbers in both files: the CSV's text is each float's shortest round trip
    j1 = table["j1"].to_pylist()
    assert [float(r[2]) for r in rows] == j1
    assert [int(r[0]) for r in rows] == table["seq"].to_pylist()

    piped = runner.invoke(app, ["export", "telemetry", pass_id, "--out", "-"])
    assert piped.exit_code == 0 and piped.stdout == (env / "t.csv").read_text()


@pytest.mark.parametrize(
    ("args", "reason"),
    [
        (("--out", "t.txt"), "--format 'txt' is not one of ['csv', 'parquet']"),
        (("--out", "-", "--format", "parquet"), "--out - writes CSV only"),
    ],
)
def test_export_refuses_what_it_cannot_write(env: Path, args: tuple[str, ...], reason: str) -> None:
    result = runner.invoke(app, ["export", "telemetry", "some-pass", *args])
    assert result.exit_code == 2 and result.output.startswith("error: ")
    assert reason in result.output


def test_export_of_an_unknown_pass_is_one_line_and_status_2(env: Path, database_url: str) -> None:
    missing = "00000000-0000-4000-8000-000000000000"
    result = runner.invoke(app, ["export", "telemetry", missing, "--out", str(env / "x.csv")])
    assert result.exit_code == 2 and "not found" in result.output
    assert not (env / "x.csv").exists()
    # which database was read (its password hidden), and how to name the demo's
    where = make_url(database_url).render_as_string(hide_password=True)
    assert f"not found in the database {where} (" in result.output
    assert "HIKOBOSHI_DATA_DIR=out/demo" in result.output
    assert len(result.output.strip().splitlines()) == 1


def test_export_quantity_across_two_imported_passes(env: Path, short_mcap: bytes) -> None:
    import csv

    source = env / "short.mcap"
    source.write_bytes(short_mcap)
    first = runner.invoke(app, ["mcap", "import", str(source)]).stdout.strip()
    second = runner.invoke(app, ["mcap", "import", str(source)]).stdout.strip()
    args = ["export", "quantity", "hw3", "--pass", first, "--pass", second, "--buckets", "8"]
    result = runner.invoke(
        app, [*args, "--out", str(env / "q.csv"), "--plot", str(env / "q.png"), "--json"]
    )
    assert result.exit_code == 0, result.output
    doc = json.loads(result.stdout)
    assert doc["field"] == "hw3" and doc["unit"] == "N m s"
    assert [p["pass_id"] for p in doc["passes"]] == [first, second]
    # the same recording twice: the same series, whole-pass and per span
    one, two = doc["passes"]
    assert one["count"] == two["count"] == 571
    assert (one["min"], one["max"], one["mean"]) == (two["min"], two["max"], two["mean"])
    assert one["buckets"] == two["buckets"] and sum(b["count"] for b in one["buckets"]) == 571
    recording = read_mcap(io.BytesIO(short_mcap))
    hw3 = recording.frames.wheel_momentum_nms[:, 2]
    assert one["min"] == hw3.min() and one["max"] == hw3.max()
    with (env / "q.csv").open(newline="") as file:
        rows = list(csv.DictReader(file))
    assert len(rows) == 2 * len(one["buckets"])
    assert [float(r["mean"]) for r in rows[: len(one["buckets"])]] == [
        b["mean"] for b in one["buckets"]
    ]
    assert (env / "q.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    table = run(*args)  # 80 columns here: the ids are cut short, the title is whole
    assert "hw3 [N m s] across 2 passes" in table and table.count("571") == 2


def test_export_quantity_refuses_a_field_with_one_line(env: Path, short_mcap: bytes) -> None:
    source = env / "short.mcap"
    source.write_bytes(short_mcap)
    pass_id = runner.invoke(app, ["mcap", "import", str(source)]).stdout.strip()
    result = runner.invoke(app, ["export", "quantity", "j9", "--pass", pass_id])
    assert result.exit_code == 2 and result.output.count("\n") == 1, result.output
    assert result.output.startswith("error: ") and "'j9'" in result.output
