"""No secret in any log (docs/security.md "Logs"): one redaction for every log record the
process writes, whichever logger wrote it.

What is redacted, wherever it appears in a record's message, its arguments or its
traceback: the value of a ``token=``-like query parameter (``token``, ``access_token``,
``api_key``, ``apikey``, ``key``, ``secret``, ``password``) and the credential of an
``Authorization`` value (``Bearer ...``, ``Basic ...``), in a header line
(``Authorization: Bearer ...``), a header pair's repr or on its own; and a command line's
``--token X``.

:func:`install_redaction` puts it in front of every logger at once: it wraps the logging
module's record factory, so that each record is redacted as it is made, before any filter
or handler (uvicorn's ``uvicorn.error`` accept lines, ``uvicorn.access``, websockets', httpx
and our own ``hikoboshi.*`` loggers alike, and handlers added later, pytest's too). The
command line installs it for ``serve``, ``spacecraft`` and ``demo``
(``hikoboshi/serve_cli.py``, ``spacecraft_cli.py`` and ``demo_cli.py``), and
:func:`server.api.http_server.uvicorn_config` for any server it configures.
:class:`RedactSecretsFilter` is the same redaction as a :class:`logging.Filter`.

Imported by the command line for the spacecraft too: this module imports nothing of the
service (the standard library only).
"""

from __future__ import annotations

import logging
import re
import threading
from collections.abc import Callable
from typing import Any

__all__ = ["REDACTED", "RedactSecretsFilter", "install_redaction", "redact", "redact_record"]

REDACTED = "[redacted]"

#: ``?token=...`` and the like: the value up to the next ``&``, space, quote or bracket
#: (a value already redacted, and whatever follows it, too: redacting twice changes nothing).
_QUERY = re.compile(
    r"(?i)([?&;](?:token|access_token|api_key|apikey|key|secret|password)=)"
    r"(?:\[redacted\])?[^&;\s\"'<>)\]]*"
)
#: ``Bearer X`` (an Authorization value, wherever it is written; X of 6 characters or
#: more, so that "bearer of" stays prose); ``Basic X`` after ``Authorization`` only
#: ("basic" is an English word).
_SCHEME = re.compile(r"(?i)(\bbearer\s+)[A-Za-z0-9._~+/=:-]{6,}")
_BASIC = re.compile(r"(?i)(\bauthorization\b['\"]?\s*[:=,]\s*(?:b?['\"])?basic\s+)[A-Za-z0-9+/=]+")
#: ``Authorization: X`` (a header line) or ``'authorization': 'X'`` (a mapping's repr):
#: the whole value when it has no scheme.
_HEADER = re.compile(
    r"(?i)(\bauthorization\b['\"]?(?>\s*[:=,]\s*(?:(?-i:b)?['\"])?))(?!(?:bearer|basic)\b|\[)"
    r"[^\s'\",;)\]}]+"
)
#: A command line's ``--token X`` (the spacecraft's).
_OPTION = re.compile(r"(?i)(--token(?:=|\s+)['\"]?)[^\s'\"]+")


def redact(text: str) -> str:
    """``text`` with every secret it shows replaced by ``[redacted]``."""
    if not text:
        return text
    text = _QUERY.sub(rf"\1{REDACTED}", text)
    text = _SCHEME.sub(rf"\1{REDACTED}", text)
    text = _BASIC.sub(rf"\1{REDACTED}", text)
    text = _HEADER.sub(rf"\1{REDACTED}", text)
    return _OPTION.sub(rf"\1{REDACTED}", text)


def redact_record(record: logging.LogRecord) -> logging.LogRecord:
    """Redact ``record`` in place: its message with its arguments (formatted here when one
    of them shows a secret: a URL object's or a header mapping's text too) and its
    traceback's text. A record whose message cannot be formatted is left as it is (the
    handler reports that as it always does)."""
    try:
        message = record.getMessage()
    except Exception:
        message = None
    if message is not None:
        clean = redact(message)
        if clean != message:
            record.msg, record.args = clean, ()
    if record.exc_info and not record.exc_text:
        # Formatter.format keeps a record's exc_text once set: the redacted one is printed.
        record.exc_text = logging.Formatter().formatException(record.exc_info)
    if record.exc_text:
        record.exc_text = redact(record.exc_text)
    if record.stack_info:
        record.stack_info = redact(record.stack_info)
    return record


class RedactSecretsFilter(logging.Filter):
    """The redaction as a filter (on a logger or a handler): it passes every record,
    redacted."""

    def filter(self, record: logging.LogRecord) -> bool:
        redact_record(record)
        return True


_lock = threading.Lock()
_installed: Callable[..., logging.LogRecord] | None = None


def install_redaction() -> None:
    """Redact every log record of this process from now on (idempotent): the logging
    module's record factory is wrapped once."""
    global _installed
    with _lock:
        current = logging.getLogRecordFactory()
        if current is _installed:
            return
        base = current

        def factory(*args: Any, **kwargs: Any) -> logging.LogRecord:
            return redact_record(base(*args, **kwargs))

        logging.setLogRecordFactory(factory)
        _installed = factory
