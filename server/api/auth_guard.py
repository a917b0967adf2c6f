"""The edge's guard against guessing tokens (docs/security.md "Failed authentications"):
failed authentications counted in fixed windows per client address and per presented
credential, known by its keyed :func:`fingerprint` and never by itself; each counted failure
goes to the ``hikoboshi.audit`` log. The edge (:mod:`server.api.edge`) and the websockets
(:mod:`server.api.deps`) ask it about failed attempts only."""

from __future__ import annotations

import hashlib
import hmac
import logging
import math
import secrets
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass

from server.settings import Settings

__all__ = ["AuthGuard", "fingerprint"]

audit = logging.getLogger("hikoboshi.audit")
log = logging.getLogger("hikoboshi.ground.edge")


@dataclass
class _Window:
    start: float
    failures: int = 0


class _Windows:
    """Fixed windows of failures by key, at most ``max_keys`` (the oldest window goes
    first)."""

    def __init__(self, window_s: float, max_keys: int) -> None:
        self.window_s = window_s
        self.max_keys = max_keys
        #: key -> its window, in the order the windows started
        self._windows: OrderedDict[str, _Window] = OrderedDict()

    def __len__(self) -> int:
        return len(self._windows)

    def get(self, key: str, now: float) -> _Window | None:
        self._expire(now)
        return self._windows.get(key)

    def count(self, key: str, now: float) -> _Window:
        """One more failure for ``key``, in its window (a new one if it has none)."""
        self._expire(now)
        window = self._windows.get(key)
        if window is None:
            window = self._windows[key] = _Window(start=now)
            while len(self._windows) > self.max_keys:
                self._windows.popitem(last=False)
        window.failures += 1
        return window

    def _expire(self, now: float) -> None:
        # Windows are appended as they start, so the expired ones are at the front.
        while self._windows:
            first = next(iter(self._windows.values()))
            if now - first.start < self.window_s:
                break
            self._windows.popitem(last=False)


#: Drawn once per process: the fingerprints of presented credentials are keyed with it, so
#: that a logged one cannot be checked against guesses offline (a mistyped password, say).
_FINGERPRINT_KEY = secrets.token_bytes(32)


def fingerprint(credential: str) -> str:
    """How a presented credential is known to the guard and the audit log: the first 16 hex
    digits of its HMAC-SHA-256 under a key drawn at start, never the credential itself
    (the same credential, the same fingerprint, for as long as the process runs)."""
    data = credential.encode("utf-8", "surrogateescape")
    digest = hmac.new(_FINGERPRINT_KEY, data, hashlib.sha256).hexdigest()
    return f"hmac:{digest[:16]}"


class AuthGuard:
    """Failed authentications in fixed windows, counted per client address and per
    presented credential (its :func:`fingerprint`): after ``limit`` failures within
    ``window_s`` of the first, a *failing* attempt from that address, or presenting that
    credential, is refused (429) until the window ends, neither checked further nor audited
    again. It is asked only about attempts that failed: a valid token is never refused
    here, and requests without a credential to public paths never meet it
    (docs/security.md "Failed authentications"). At most ``max_addresses`` addresses and as
    many credentials are tracked (the oldest window goes first); ``clock`` is injectable
    (tests move it instead of sleeping)."""

    def __init__(
        self,
        *,
        limit: int,
        window_s: float,
        max_addresses: int,
        clock: Callable[[], float] = time.monotonic,
        on_blocked: Callable[[str, int, float], None] | None = None,
    ) -> None:
        self.limit = limit
        #: called once per window an address is blocked: (address, failures, seconds left)
        self.on_blocked = on_blocked
        self.window_s = window_s
        self.max_addresses = max_addresses
        self.clock = clock
        self._addresses = _Windows(window_s, max_addresses)
        self._credentials = _Windows(window_s, max_addresses)

    @classmethod
    def of(
        cls, settings: Settings, on_blocked: Callable[[str, int, float], None] | None = None
    ) -> AuthGuard:
        """A guard with the settings' limit, window and tracked addresses."""
        return cls(
            limit=settings.auth_failure_limit,
            window_s=settings.auth_failure_window_s,
            max_addresses=settings.auth_tracked_addresses,
            on_blocked=on_blocked,
        )

    def __len__(self) -> int:
        """Addresses tracked."""
        return len(self._addresses)

    def credentials_tracked(self) -> int:
        return len(self._credentials)

    def retry_after(self, address: str, credential: str | None = None) -> int | None:
        """Seconds until a failing attempt from ``address`` presenting ``credential`` is
        heard again, or None when neither is over the limit."""
        now = self.clock()
        keys = [(self._addresses, address)]
        if credential is not None:
            keys.append((self._credentials, fingerprint(credential)))
        left: float | None = None
        for windows, key in keys:
            window = windows.get(key, now)
            if window is not None and window.failures >= self.limit:
                end = window.start + self.window_s - now
                left = end if left is None else max(left, end)
        return None if left is None else max(1, math.ceil(left))

    def failed(self, address: str, path: str, reason: str, credential: str | None = None) -> None:
        """Audit one failed authentication and count it against ``address`` and the
        credential presented (if any)."""
        now = self.clock()
        window = self._addresses.count(address, now)
        key = None if credential is None else fingerprint(credential)
        audit.warning(
            "authentication failed: address=%s credential=%s path=%r reason=%r (%d in this window)",
            address,
            key or "none",
            path,
            reason,
            window.failures,
            extra={
                "fields": {
                    "event": "authentication_failed",
                    "address": address,
                    "credential": key,
                    "path": path,
                    "reason": reason,
                    "failures": window.failures,
                }
            },
        )
        if window.failures == self.limit:
            left = window.start + self.window_s - now
            audit.warning(
                "address %s refused for %.0f s: %d failed authentications",
                address,
                left,
                window.failures,
                extra={
                    "fields": {
                        "event": "address_refused",
                        "address": address,
                        "refused_s": round(left, 1),
                        "failures": window.failures,
                    }
                },
            )
            if self.on_blocked is not None:
                try:
                    self.on_blocked(address, window.failures, left)
                except Exception:
                    log.exception("recording the block of %s failed", address)
        if key is not None:
            held = self._credentials.count(key, now)
            if held.failures == self.limit:
                audit.warning(
                    "credential %s refused for %.0f s: %d failed authentications",
                    key,
                    held.start + self.window_s - now,
                    held.failures,
                    extra={
                        "fields": {
                            "event": "credential_refused",
                            "credential": key,
                            "refused_s": round(held.start + self.window_s - now, 1),
                            "failures": held.failures,
                        }
                    },
                )
