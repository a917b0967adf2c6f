"""The one logging configuration of ``hikoboshi serve``, ``spacecraft`` and ``demo``
(docs/operations.md "Logs").

Every line has its time (UTC, ISO 8601, milliseconds), level, logger and message, and the
pass it concerns where there is one: the record's ``pass_id`` (``extra={"pass_id": ...}``)
or, else, :data:`current_pass` (a context variable the pass runner sets in its pass's task,
so that whatever that task logs names it). A record's ``fields`` (``extra={"fields":
{...}}``: the audit log's address, credential fingerprint, path, reason) are written as
``key=value`` after a text line's message, and as members of a JSON line.

Two formats: ``text`` (one line, for a terminal) and ``json`` (one object a line, for a log
collector). Every line is redacted once more as a whole (:func:`server.redaction.redact`),
``fields`` included: the record factory's redaction (installed here too) sees only the
message, its arguments and its traceback.

Like :mod:`server.redaction`, this module imports the standard library only: the command
line uses it for the spacecraft too.
"""

from __future__ import annotations

import contextvars
import json
import logging
import sys
from datetime import UTC, datetime
from typing import IO, Any

from server.redaction import install_redaction, redact

__all__ = [
    "LOG_FORMATS",
    "LOG_LEVELS",
    "JsonFormatter",
    "TextFormatter",
    "check_log_options",
    "configure_logging",
    "current_log_config",
    "current_pass",
]

LOG_FORMATS = ("text", "json")
LOG_LEVELS = ("debug", "info", "warning", "error")

#: The pass the running code works for (set by the pass runner in its pass's task).
current_pass: contextvars.ContextVar[str | None] = contextvars.ContextVar(
    "hikoboshi_current_pass", default=None
)

#: The handler :func:`configure_logging` put on the root logger (replaced on a second call).
_HANDLER_NAME = "hikoboshi"
#: (format, level) of the last :func:`configure_logging` in this process: handed to the
#: worker pool's job processes, which log the same way (server/services/jobs.py).
_configured: tuple[str, str] | None = None


def current_log_config() -> tuple[str, str] | None:
    """``(format, level)`` as :func:`configure_logging` last set them here, or None."""
    return _configured


def _timestamp(record: logging.LogRecord) -> str:
    stamp = datetime.fromtimestamp(record.created, UTC)
    return stamp.strftime("%Y-%m-%dT%H:%M:%S.") + f"{stamp.microsecond // 1000:03d}Z"


def _pass_id(record: logging.LogRecord) -> str | None:
    value = getattr(record, "pass_id", None)
    return str(value) if value is not None else current_pass.get()


def _fields(record: logging.LogRecord) -> dict[str, Any]:
    value = getattr(record, "fields", None)
    return dict(value) if isinstance(value, dict) else {}


def _exception_text(formatter: logging.Formatter, record: logging.LogRecord) -> str | None:
    if record.exc_info and not record.exc_text:
        record.exc_text = formatter.formatException(record.exc_info)
    return record.exc_text or None


class TextFormatter(logging.Formatter):
    """``2026-11-27T08:41:46.123Z WARNING hikoboshi.audit [pass p-1] message key=value``."""

    def format(self, record: logging.LogRecord) -> str:
        parts = [_timestamp(record), record.levelname, record.name]
        pass_id = _pass_id(record)
        if pass_id is not None:
            parts.append(f"[pass {pass_id}]")
        # One record, one line: a message's own line breaks are written \n (no forged lines).
        message = record.getMessage().replace("\r", "\\r").replace("\n", "\\n")
        parts.append(message)
        # The fields the message does not already show (audit lines write them in prose).
        parts += [
            f"{k}={_text_value(v)}" for k, v in _fields(record).items() if f"{k}=" not in message
        ]
        line = " ".join(parts)
        if (exc := _exception_text(self, record)) is not None:
            line += "\n" + exc
        if record.stack_info:
            line += "\n" + self.formatStack(record.stack_info)
        return redact(line)


def _text_value(value: Any) -> str:
    text = str(value)
    return json.dumps(text) if (not text or any(c.isspace() or c in "\"'=" for c in text)) else text


class JsonFormatter(logging.Formatter):
    """One JSON object a line: ``time``, ``level``, ``logger``, ``message``, ``pass_id``
    (when there is one), the record's ``fields``, and ``exception`` (its traceback)."""

    def format(self, record: logging.LogRecord) -> str:
        doc: dict[str, Any] = {
            "time": _timestamp(record),
            "level": record.levelname,
            "logger": record.name,
            "message": record.getMessage(),
        }
        pass_id = _pass_id(record)
        if pass_id is not None:
            doc["pass_id"] = pass_id
        for key, value in _fields(record).items():
            doc.setdefault(key, value)
        if (exc := _exception_text(self, record)) is not None:
            doc["exception"] = exc
        if record.stack_info:
            doc["stack"] = self.formatStack(record.stack_info)
        return redact(json.dumps(doc, default=str, ensure_ascii=False))


def check_log_options(log_format: str, level: str) -> None:
    """``ValueError`` with the reason unless ``log_format`` and ``level`` are known."""
    if log_format not in LOG_FORMATS:
        raise ValueError(f"--log-format {log_format!r} is not one of {', '.join(LOG_FORMATS)}")
    if level.lower() not in LOG_LEVELS:
        raise ValueError(f"--log-level {level!r} is not one of {', '.join(LOG_LEVELS)}")


def configure_logging(
    log_format: str = "text", level: str = "info", *, stream: IO[str] | None = None
) -> logging.Handler:
    """Send every logger's records (ours, uvicorn's, websockets') at ``level`` and above to
    ``stream`` (stderr) in ``log_format``, redacted; the handler it installed (a second call
    replaces it). ``ValueError`` for an unknown format or level."""
    global _configured
    check_log_options(log_format, level)
    _configured = (log_format, level.lower())
    install_redaction()
    handler = logging.StreamHandler(sys.stderr if stream is None else stream)
    handler.set_name(_HANDLER_NAME)
    handler.setFormatter(JsonFormatter() if log_format == "json" else TextFormatter())
    root = logging.getLogger()
    for old in [h for h in root.handlers if h.get_name() == _HANDLER_NAME]:
        root.removeHandler(old)
        old.close()
    root.addHandler(handler)
    root.setLevel(level.upper())
    # uvicorn's loggers go through the root's handler too (uvicorn is given no log config).
    for name in ("uvicorn", "uvicorn.error", "uvicorn.access"):
        logger = logging.getLogger(name)
        logger.handlers.clear()
        logger.propagate = True
    return handler
