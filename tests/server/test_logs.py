"""The one logging configuration (server/logs.py): its two formats, the pass id, the audit
lines' fields, the redaction kept; and a real ``hikoboshi serve``'s lines in each format for
a start and an authentication failure."""

from __future__ import annotations

import asyncio
import io
import json
import logging
import re
import subprocess
from collections.abc import Callable, Iterator
from pathlib import Path

import httpx
import pytest

from server.logs import configure_logging, current_pass
from server.redaction import redact
from tests.support.processes import (
    free_port,
    health_when_up,
    serve_command,
    serve_env,
    stderr_of_stopped,
)

SECRET = "sEcReT-0123456789abcdef"
#: UTC, ISO 8601, milliseconds
STAMP = r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z"


@pytest.fixture()
def captured() -> Iterator[Callable[[str], io.StringIO]]:
    """Everything logged at debug and above, as configured for ``serve``, into a buffer;
    the root logger as it was afterwards."""
    root = logging.getLogger()
    level, handlers, factory = root.level, list(root.handlers), logging.getLogRecordFactory()
    # uvicorn's loggers as serve leaves them (to the root), not as a uvicorn.Config of an
    # earlier test in this worker left them (its own handlers, no propagation, warning)
    uvicorn = [logging.getLogger(n) for n in ("uvicorn", "uvicorn.access", "uvicorn.error")]
    kept = [(lg, lg.level, lg.propagate, list(lg.handlers)) for lg in uvicorn]
    for lg in uvicorn:
        lg.setLevel(logging.NOTSET)
        lg.propagate = True
        lg.handlers[:] = []
    stream = io.StringIO()
    holder: list[logging.Handler] = []

    def configure(log_format: str) -> io.StringIO:
        holder.append(configure_logging(log_format, "debug", stream=stream))
        return stream

    yield configure
    for handler in holder:
        root.removeHandler(handler)
    root.handlers[:] = handlers
    root.setLevel(level)
    logging.setLogRecordFactory(factory)
    for lg, lg_level, propagate, lg_handlers in kept:
        lg.setLevel(lg_level)
        lg.propagate = propagate
        lg.handlers[:] = lg_handlers


def test_a_text_line(captured: Callable[[str], io.StringIO]) -> None:
    stream = captured("text")
    logging.getLogger("hikoboshi.ground.runner").info(
        "pass %s started", "demo", extra={"pass_id": "p-1", "fields": {"commands": 3}}
    )
    (line,) = stream.getvalue().splitlines()
    assert re.fullmatch(
        rf"{STAMP} INFO hikoboshi\.ground\.runner \[pass p-1\] pass demo started commands=3", line
    ), line


def test_a_json_line_with_the_pass_of_the_running_task(
    captured: Callable[[str], io.StringIO],
) -> None:
    stream = captured("json")
    log = logging.getLogger("hikoboshi.ground.link")

    async def in_a_pass() -> None:
        log.warning("late frame", extra={"fields": {"seq": 7, "path": f"/x?token={SECRET}"}})

    async def main() -> None:
        named = current_pass.set("p-42")
        try:
            task = asyncio.create_task(in_a_pass())  # copies the context, as the runner does
        finally:
            current_pass.reset(named)
        await task
        log.info("after the pass")  # no pass here

    asyncio.run(main())
    records = [json.loads(line) for line in stream.getvalue().splitlines()]
    first, second = [r for r in records if r["logger"].startswith("hikoboshi.")]
    assert re.fullmatch(STAMP, first["time"])
    assert (first["level"], first["logger"], first["message"]) == (
        "WARNING",
        "hikoboshi.ground.link",
        "late frame",
    )
    assert first["pass_id"] == "p-42" and first["seq"] == 7
    assert first["path"] == "/x?token=[redacted]"  # fields are redacted too
    assert "pass_id" not in second and second["message"] == "after the pass"
    assert SECRET not in stream.getvalue()


def test_the_record_factorys_redaction_still_applies(
    captured: Callable[[str], io.StringIO],
) -> None:
    stream = captured("text")
    logging.getLogger("uvicorn.access").info(
        '%s - "%s %s HTTP/1.1" %d', "127.0.0.1:1", "GET", f"/api/passes?token={SECRET}", 401
    )
    logging.getLogger("hikoboshi.x").error("Authorization: Bearer %s", SECRET)
    text = stream.getvalue()
    assert SECRET not in text
    assert "/api/passes?token=[redacted] HTTP/1.1" in text  # once, not twice
    assert "Bearer [redacted]" in text


def test_redaction_is_idempotent() -> None:
    for text in (
        f"GET /a?token={SECRET}&x=1",
        "?token=[redacted]",
        f"Authorization: Bearer {SECRET}",
        f"hikoboshi spacecraft --token {SECRET}",
    ):
        once = redact(text)
        assert redact(once) == once and SECRET not in once
    assert redact(f"?token=[redacted]{SECRET}") == "?token=[redacted]"


def test_unknown_format_or_level_is_refused() -> None:
    with pytest.raises(ValueError, match="--log-format 'xml'"):
        configure_logging("xml", "info")
    with pytest.raises(ValueError, match="--log-level 'loud'"):
        configure_logging("text", "loud")


@pytest.mark.parametrize("log_format", ["text", "json"])
def test_a_real_serve_logs_its_start_and_a_failed_authentication(
    tmp_path: Path, log_format: str
) -> None:
    port = free_port()
    # the log format as a container sets it
    env = serve_env(tmp_path, "v-token-0123456789=vera:viewer", HIKOBOSHI_LOG_FORMAT=log_format)
    proc = subprocess.Popen(
        serve_command(port), env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
    )
    try:
        base = f"http://127.0.0.1:{port}"
        health_when_up(proc, base, request_timeout_s=2.0)
        wrong = {"Authorization": f"Bearer {SECRET}"}
        assert httpx.get(f"{base}/api/passes?token={SECRET}", headers=wrong).status_code == 401
    finally:
        proc.terminate()
        err = stderr_of_stopped(proc, 30.0)
    lines = [line for line in err.splitlines() if line.strip()]
    assert SECRET not in err
    if log_format == "json":
        assert [line for line in lines if not line.startswith("{")] == [], err[-3000:]
        records = [json.loads(line) for line in lines]
        assert all(re.fullmatch(STAMP, r["time"]) for r in records)
        started = [r for r in records if "Uvicorn running on" in r["message"]]
        assert [(r["level"], r["logger"]) for r in started] == [("INFO", "uvicorn.error")]
        (failed,) = [r for r in records if r.get("event") == "authentication_failed"]
        assert (failed["level"], failed["logger"]) == ("WARNING", "hikoboshi.audit")
        assert failed["address"] == "127.0.0.1" and failed["path"] == "/api/passes"
        assert failed["reason"] == "unknown API token" and failed["failures"] == 1
        assert failed["credential"].startswith("hmac:")
    else:
        assert any(
            re.fullmatch(rf"{STAMP} INFO uvicorn\.error Uvicorn running on http://\S+ .*", line)
            for line in lines
        ), lines
        failed_lines = [line for line in lines if "hikoboshi.audit" in line]
        assert len(failed_lines) == 1, lines
        assert re.fullmatch(
            rf"{STAMP} WARNING hikoboshi\.audit authentication failed: address=127\.0\.0\.1 "
            r"credential=hmac:\w+ path='/api/passes' reason='unknown API token' "
            r"\(1 in this window\) event=authentication_failed failures=1",
            failed_lines[0],
        ), failed_lines[0]


def _warn_from_a_job() -> int:
    logging.getLogger("hikoboshi.ground.analyses").warning("analysis %s failed", "resim")
    return 7


def test_a_job_process_logs_as_the_server_does(capfd: pytest.CaptureFixture[str]) -> None:
    """The worker pool hands its job processes the server's log configuration
    (``current_log_config``): a job's warning is a JSON line, not the bare message of
    Python's last-resort handler."""
    import multiprocessing

    from server.services.jobs import run_job

    ctx = multiprocessing.get_context("fork")
    receiver, sender = ctx.Pipe(duplex=False)
    process = ctx.Process(
        target=run_job,
        args=(sender, None, _warn_from_a_job, (), {}, None, ("json", "info")),
    )
    process.start()
    sender.close()
    assert receiver.poll(60.0)  # a guard, not a timing assertion
    assert receiver.recv() == ("ok", 7)
    process.join(60.0)
    lines = [line for line in capfd.readouterr().err.splitlines() if line.startswith("{")]
    (record,) = [json.loads(line) for line in lines]
    assert record["message"] == "analysis resim failed"
    assert (record["level"], record["logger"]) == ("WARNING", "hikoboshi.ground.analyses")
    assert re.fullmatch(STAMP, record["time"])
