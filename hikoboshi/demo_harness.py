"""What both demos (:mod:`hikoboshi.demo`, :mod:`hikoboshi.campaign_demo`) run on: the
ground service in a thread on loopback (as ``hikoboshi serve`` runs it), fresh API tokens,
the simulated spacecraft as its own process (``hikoboshi spacecraft``, its token in its
environment), a small client for the ground's REST API, and the polls that follow a pass:
until the spacecraft is connected, until the pass ends (sampling the link's onboard clock
mapping), until its commands are resolved and its telemetry window is past.

Only public interfaces are used: REST, the link websocket, process signals.
"""

from __future__ import annotations

import json
import os
import secrets
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Protocol, TypedDict, Unpack

from hikoboshi.demo_summary import TERMINAL_STATES, OnboardClock
from server.settings import ApiToken, Role, Settings

__all__ = ["DemoError", "Progress", "VehicleOptions", "spacecraft_command"]

#: Progress callback: (phase, done, total).
Progress = Callable[[str, float, float], None]


class DemoError(RuntimeError):
    """The demo could not run to the end; the message says where it stopped."""


class _Send(TypedDict, total=False):
    """How :class:`_Api` sends a request: its timeout (120 s unless given), a body that is
    JSON already."""

    timeout_s: float
    data: bytes | None


class _Api:
    """A small JSON client for the ground's REST API (the standard library's urllib);
    ``logs``: where its log is, said when the ground does not answer."""

    def __init__(
        self, base: str, token: str, logs: str = "its log is ground.log in the output folder"
    ) -> None:
        self.base = base
        self._token = token
        self._logs = logs

    def call(self, method: str, path: str, body: Any = None, **send: Unpack[_Send]) -> Any:
        """The answer's JSON (:meth:`raw`'s bytes, read)."""
        return json.loads(self.raw(method, path, body, **send))

    def raw(self, method: str, path: str, body: Any = None, **send: Unpack[_Send]) -> bytes:
        """The answer's bytes; ``body`` sent as JSON, or ``data`` (JSON already) as it is."""
        timeout_s = send.get("timeout_s", 120.0)
        data = send.get("data")
        if data is None and body is not None:
            data = json.dumps(body).encode()
        request = urllib.request.Request(
            self.base + path,
            data=data,
            method=method,
            headers={"Authorization": f"Bearer {self._token}", "Content-Type": "application/json"},
        )
        try:
            with urllib.request.urlopen(request, timeout=timeout_s) as response:
                body_out: bytes = response.read()
                return body_out
        except urllib.error.HTTPError as exc:
            raise DemoError(f"{method} {path}: {exc.code} {_problem(exc.read())}") from None
        except (TimeoutError, urllib.error.URLError) as exc:
            # a ground that does not answer (overloaded, or gone): a reason, not a traceback
            reason = getattr(exc, "reason", exc)  # URLError's reason, or the timeout itself
            if isinstance(reason, ConnectionRefusedError):
                raise DemoError(
                    f"{method} {path}: {self.base} refused the connection; {self._logs}"
                ) from None
            raise DemoError(
                f"{method} {path}: no answer from the ground service within {timeout_s:g} s"
                f" ({reason}); {self._logs}"
            ) from None


def _problem(body: bytes) -> str:
    """An error's answer in one line: ``code: detail`` of its problem details (RFC 9457),
    else its first 500 characters."""
    try:
        problem = json.loads(body)
        return f"{problem['code']}: {problem['detail']}"
    except (ValueError, KeyError, TypeError):
        return body.decode(errors="replace")[:500]


def _port(preferred: int) -> int:
    """``preferred`` if it is free on loopback, else any free port."""
    for candidate in (preferred, 0):
        with socket.socket() as sock:
            try:
                sock.bind(("127.0.0.1", candidate))
            except OSError:
                continue
            return int(sock.getsockname()[1])
    raise DemoError("no free port on 127.0.0.1")


@contextmanager
def _ground(settings: Settings, port: int) -> Iterator[None]:
    # The application and uvicorn are imported here, not with the module (1.5 of its 2 s of
    # imports, measured): hikoboshi demo checks its options with this module first.
    import uvicorn

    from server.api.http_server import uvicorn_config
    from server.app import create_app

    # As `hikoboshi serve` runs it: forwarded headers believed from no one, logs redacted.
    config = uvicorn_config(
        create_app(settings), settings, host="127.0.0.1", port=port, log_level="warning"
    )
    server = uvicorn.Server(config)
    thread = threading.Thread(target=server.run, name="ground", daemon=True)
    thread.start()
    deadline = time.monotonic() + 60.0
    while not server.started:
        if not thread.is_alive() or time.monotonic() > deadline:
            raise DemoError(f"the ground service did not start on port {port}")
        time.sleep(0.02)
    try:
        yield
    finally:
        server.should_exit = True
        thread.join(timeout=60.0)


class VehicleOptions(Protocol):
    """What a demo's options say of its simulated vehicle (both demos' options have it)."""

    @property
    def speed(self) -> float: ...
    @property
    def loss(self) -> float: ...
    @property
    def seed(self) -> int: ...
    @property
    def log_format(self) -> str: ...
    @property
    def log_level(self) -> str: ...


def spacecraft_command(port: int, options: VehicleOptions) -> list[str]:
    """``hikoboshi spacecraft``'s command line for a demo's vehicle on ``port``, before its
    demo's own options (its token goes in its environment, never here)."""
    return [
        sys.executable,
        "-m",
        "hikoboshi",
        "spacecraft",
        "--ground",
        f"ws://127.0.0.1:{port}/api/link",
        "--log-format",
        options.log_format,
        "--log-level",
        options.log_level,
        "--time-scale",
        repr(options.speed),
        "--loss",
        repr(options.loss),
        "--seed",
        str(options.seed),
    ]


@contextmanager
def _spacecraft(
    args: list[str], log_path: Path, env: dict[str, str]
) -> Iterator[subprocess.Popen[bytes]]:
    with log_path.open("wb") as log:
        proc = subprocess.Popen(
            args, stdout=log, stderr=subprocess.STDOUT, env={**os.environ, **env}
        )
    try:
        yield proc
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout=120.0)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def _tokens(out: Path) -> dict[str, ApiToken]:
    tokens = {
        secrets.token_urlsafe(18): ApiToken(name="demo-operator", role=Role.OPERATOR),
        secrets.token_urlsafe(18): ApiToken(name="demo-viewer", role=Role.VIEWER),
        secrets.token_urlsafe(18): ApiToken(name="ets-vii", role=Role.SPACECRAFT),
    }
    # For `hikoboshi serve` on the same data afterwards (HIKOBOSHI_TOKENS=...).
    line = ",".join(f"{t}={a.name}:{a.role.value}" for t, a in tokens.items())
    path = out / "tokens"
    path.write_text(line + "\n")
    os.chmod(path, 0o600)
    return tokens


def _token_of(tokens: dict[str, ApiToken], role: Role) -> str:
    return next(t for t, a in tokens.items() if a.role is role)


def _all(api: _Api, path: str, key: str, page: int = 1000) -> list[dict[str, Any]]:
    """Every item of a paged listing (``offset``/``limit``, ``count`` the total)."""
    items: list[dict[str, Any]] = []
    sep = "&" if "?" in path else "?"
    while True:
        body = api.call("GET", f"{path}{sep}offset={len(items)}&limit={page}")
        batch = body[key]
        items.extend(batch)
        if not batch or len(items) >= int(body["count"]):
            return items


def _wait_connected(api: _Api, proc: subprocess.Popen[bytes]) -> None:
    deadline = time.monotonic() + 60.0
    while not api.call("GET", "/api/link/status")["connected"]:
        if proc.poll() is not None:
            raise DemoError(f"the spacecraft process exited with {proc.returncode}")
        if time.monotonic() > deadline:
            raise DemoError("the spacecraft did not connect within 60 s")
        time.sleep(0.1)


def _start(api: _Api, pass_id: str, name: str) -> int:
    """Start the pass (its confirmation typed as an operator types it); its epoch (ns)."""
    started = api.call("POST", f"/api/passes/{pass_id}/start", {"confirm": f"START {name}"})
    return int(started["epoch_ns"])


def _drain(proc: subprocess.Popen[bytes], report: Progress) -> None:
    """Stop the spacecraft (SIGTERM: it downlinks what its telemetry store still holds
    first) and wait for it to end, at most 120 s."""
    report("draining the onboard telemetry store", 0, 1)
    proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(timeout=120.0)
    except subprocess.TimeoutExpired:
        raise DemoError("the spacecraft did not drain its telemetry in 120 s") from None
    report("draining the onboard telemetry store", 1, 1)


def _settle(api: _Api, pass_id: str, speed: float, timeout_s: float = 60.0) -> None:
    """Before the spacecraft stops: let the onboard clock pass the end of the pass's
    telemetry window (every frame of it generated; the drain delivers them: a safed pass's
    runs on a minute onboard past the safing) and the ground resolve the commands still in
    flight (an abort or a safing leaves some). ``timeout_s`` wall s beyond the window's
    rest at ``speed``."""
    deadline: float | None = None
    while deadline is None or time.monotonic() < deadline:
        summary = api.call("GET", f"/api/passes/{pass_id}/summary")
        onboard = api.call("GET", "/api/link/status").get("onboard_time_ns")
        end = summary["telemetry_end_ns"]
        if deadline is None:
            rest_s = 0.0 if end is None or onboard is None else max(0, end - onboard) / 1e9
            deadline = time.monotonic() + timeout_s + rest_s / speed
        if (
            end is not None
            and onboard is not None
            and onboard >= end
            and summary["commands_outstanding"] == 0
        ):
            return
        time.sleep(0.25)


def _follow(
    api: _Api,
    proc: subprocess.Popen[bytes],
    pass_id: str,
    epoch_ns: int,
    duration_s: float,
    timeout_s: float,
    report: Progress,
    sampler: _ClockSampler,
) -> str:
    """Poll the pass until it ends (``complete``, ``aborted`` or ``safed``); its final
    state. Each link status read is a sample of the ground's onboard clock mapping."""
    deadline = time.monotonic() + timeout_s
    while True:
        record = api.call("GET", f"/api/passes/{pass_id}")
        if record["state"] in TERMINAL_STATES:
            report("pass", duration_s, duration_s)
            return str(record["state"])
        if proc.poll() is not None:
            raise DemoError(f"the spacecraft process exited with {proc.returncode} mid-pass")
        if time.monotonic() > deadline:
            raise DemoError(f"the pass did not end within {timeout_s:.0f} s")
        before_ns = time.time_ns()
        status = api.call("GET", "/api/link/status")
        after_ns = time.time_ns()
        onboard = status.get("onboard_time_ns")
        sampler.offer(before_ns, after_ns, onboard, status.get("time_scale"))
        if onboard is not None:
            t_s = min(duration_s, max(0.0, (onboard - epoch_ns) / 1e9))
            report("pass", t_s, duration_s)
        time.sleep(0.25)


class _ClockSampler:
    """The narrowest read of the ground's onboard clock mapping (``GET /api/link/status``
    between two readings of the wall clock: the ground's ``SystemClock`` reads the same
    ``time.time_ns`` in this process); the latest of equally narrow ones."""

    def __init__(self) -> None:
        self._best: tuple[int, int, int, float] | None = None  # width, mid, onboard, scale

    def offer(self, before_ns: int, after_ns: int, onboard_ns: Any, scale: Any) -> None:
        if onboard_ns is None or not scale:
            return
        width = after_ns - before_ns
        if self._best is None or width <= self._best[0]:
            self._best = (width, (before_ns + after_ns) // 2, int(onboard_ns), float(scale))

    def clock(self, start_ns: int | None) -> OnboardClock:
        if self._best is None:
            return OnboardClock(start_ns=start_ns)
        width, mid, onboard, scale = self._best
        return OnboardClock(start_ns, mid, onboard, scale, round(width / 2e9 * scale, 3))
