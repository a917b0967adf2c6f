"""Command authority: this ground commands the vehicle only while it holds the vehicle's
lease (:mod:`server.storage.lease`), and is a **standby** otherwise.

:class:`CommandAuthority` keeps the lease from a thread of its own, on a database connection
of its own (so a busy event loop or a backlog of writes never delays a renewal):

- **Holder.** Renewed every :attr:`LeasePolicy.renew_s`; the ground may command
  (:meth:`CommandAuthority.may_command`) until ``ttl_s - renew_s`` after the start of its
  last successful renewal, on its own monotonic clock, which ends before the database can
  count the lease as expired (the holder stops sending before any standby may start).
  A renewal that fails because the database does not answer leaves the lease *lapsing*:
  nothing more is sent once that time has passed (the vehicle flies what it holds), and a
  later renewal with the token unchanged makes it valid again. A renewal that finds another
  token means the lease was taken: the ground **stands down** (``on_lost``: the pass's
  uplink stops, the vehicle's link closes, nothing is written) and becomes a standby.
- **Standby.** Tries to acquire the lease at every renewal period; when the holder of record
  is gone (its expiry has passed on the database's clock, or it released the lease at a
  graceful stop) it acquires it with the next fencing token and ``on_acquired`` runs (the
  same recovery as a restart: resume the running pass from the database and the vehicle's
  ``hello``).
- **Fencing.** :meth:`CommandAuthority.fence` runs first in every transaction of the
  command path (:class:`server.services.dbworker.Database`): a write under a stale token is
  refused by the database (:class:`~server.storage.errors.LeaseLost`), never applied; a
  standby's transactions are read-only (``SET TRANSACTION READ ONLY``), so it reads the
  record and writes nothing. SQLite has no standby: its one ground takes the lease before
  its first transaction.

On SQLite the service holds an exclusive lock on the database file's lock file
(:func:`hold_sqlite_file`): a second ground on the same file is refused at its start, and
the one ground takes the lease whoever the row names (the lock proves the previous holder is
gone) and keeps it without renewals (``exclusive``: a renewal would queue for SQLite's one
write lock behind the command path's own writes, and nothing could take the lease anyway).
"""

from __future__ import annotations

import asyncio
import contextlib
import fcntl
import logging
import os
import socket
import threading
import time
import uuid
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

from sqlalchemy.orm import Session, sessionmaker

from server.services.errors import ConflictError
from server.storage import lease as leases
from server.storage.errors import LeaseLost
from server.storage.lease import Lease, LeaseRow

__all__ = [
    "CommandAuthority",
    "LeasePolicy",
    "SecondGround",
    "ground_name",
    "hold_sqlite_file",
]

log = logging.getLogger("hikoboshi.ground.authority")


class SecondGround(RuntimeError):
    """Another ground service already uses this SQLite database file."""


def ground_name(given: str | None = None) -> str:
    """This process's name as a lease holder: the given name (a setting) or the host's, with
    the process id and a random suffix, so a restarted ground is never taken for the one that
    held the lease before it."""
    base = given or socket.gethostname() or "ground"
    return f"{base[:80]}:{os.getpid()}:{uuid.uuid4().hex[:8]}"


def hold_sqlite_file(database: Path) -> IO[str]:
    """An exclusive lock on ``<database>.ground.lock``, held as long as the returned file
    is open (the kernel drops it when the process dies, kill -9 included). Raises
    :class:`SecondGround`, naming the process that holds it, when another ground does."""
    path = database.with_name(database.name + ".ground.lock")
    path.parent.mkdir(parents=True, exist_ok=True)
    handle = open(path, "a+")  # noqa: SIM115 (held open for the service's life)
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        handle.seek(0)
        holder = handle.read().strip() or "another process"
        handle.close()
        raise SecondGround(
            f"another ground service ({holder}) is using the SQLite database {database}: "
            "SQLite serves one ground; stop it first, or run both grounds on PostgreSQL "
            "(HIKOBOSHI_DATABASE_URL), where the second is a hot standby"
        ) from None
    handle.seek(0)
    handle.truncate()
    handle.write(f"pid {os.getpid()} on {socket.gethostname()}\n")
    handle.flush()
    return handle


@dataclass(frozen=True)
class LeasePolicy:
    """The lease's name (one per vehicle), this ground's name, its time to live and how often
    it is renewed (wall s; settings ``command_lease``, ``ground_name``, ``lease_ttl_s``,
    ``lease_renew_s``), and whether this ground is the only one by construction
    (``exclusive``: SQLite's file lock is held, so the lease is taken whoever the row names
    and never lapses: no other ground can exist to take it)."""

    name: str
    holder: str
    ttl_s: float = 10.0
    renew_s: float = 1.0
    exclusive: bool = False

    def __post_init__(self) -> None:
        if not 0 < self.renew_s < self.ttl_s / 2:
            raise ValueError(
                f"lease renewal every {self.renew_s} s must be under half its "
                f"time to live ({self.ttl_s} s)"
            )


Callback = Callable[[], Awaitable[None]]
LostCallback = Callable[[str], Awaitable[None]]


class CommandAuthority:
    """The lease's keeper (see the module docstring)."""

    def __init__(
        self,
        sessions: sessionmaker[Session],
        policy: LeasePolicy,
        *,
        monotonic: Callable[[], float] = time.monotonic,
    ) -> None:
        self._sessions = sessions
        self.policy = policy
        self._monotonic = monotonic
        self._guard = threading.Lock()
        self._lease: Lease | None = None
        self._valid_until = 0.0  # monotonic s: may command before this
        self._seen: LeaseRow | None = None  # the lease as last read, when not ours
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._on_acquired: Callback | None = None
        self._on_lost: LostCallback | None = None
        self._serial: asyncio.Lock | None = None
        #: a takeover's first steps run (the link waits: :meth:`settled`)
        self._settling = False
        #: the service is stopping (:meth:`stop_commanding`); it gave its lease up (:meth:`close`)
        self._stopping = False
        self._released = False
        #: counted for /metrics
        self.acquisitions = 0
        self.losses = 0
        self.renewal_failures = 0
        self.database_reachable = True

    # -- what the ground asks ------------------------------------------------------------

    @property
    def lease(self) -> Lease | None:
        return self._lease

    @property
    def holder(self) -> bool:
        """Whether this ground holds the lease (lapsing or not)."""
        return self._lease is not None

    def may_command(self) -> bool:
        """Whether this ground may send to the vehicle now: it holds the lease and its last
        renewal is recent enough (see the module docstring)."""
        if self._lease is None or self._stopping:
            return False
        return self.policy.exclusive or self._monotonic() < self._valid_until

    def refusal(self) -> ConflictError | None:
        """Why an operator's start or abort, or the vehicle's link, is refused here (None:
        this ground commands)."""
        if self.may_command():
            if not self._settling:
                return None
            return ConflictError(
                "taking_over",
                "this ground has just taken the command lease over and is settling what the "
                "ground gone left: try again in a moment",
                self.status(),
            )
        status = self.status()
        if self._stopping:
            return ConflictError(
                "stopping",
                "this ground is stopping: its pass is handed to the vehicle, and the ground in "
                "command next resumes it",
                status,
            )
        if self._lease is not None:
            return ConflictError(
                "command_lease_lapsing",
                "this ground cannot renew its command lease (the database does not answer): "
                "it sends nothing until it can",
                status,
            )
        return ConflictError(
            "standby",
            f"this ground is a standby: {status['lease_holder'] or 'no ground'} holds the "
            f"command lease {self.policy.name!r}; send commands to the ground in command",
            status,
        )

    def status(self) -> dict[str, Any]:
        """For /api/health, /api/ready, /metrics and the consoles."""
        lease, seen = self._lease, self._seen
        role = "holder" if lease is not None else "standby"
        out: dict[str, Any] = {
            "role": role,
            "ground": self.policy.holder,
            "lease": self.policy.name,
            "commanding": self.may_command(),
            "token": None if lease is None else lease.token,
            "lease_holder": self.policy.holder if lease is not None else None,
            "database_reachable": self.database_reachable,
        }
        if lease is None and seen is not None and seen.held:
            out["lease_holder"] = seen.holder
            out["lease_token"] = seen.token
        return out

    def fence(self, session: Session) -> None:
        """First in every command-path transaction (see the module docstring). A standby's
        transactions are read-only in the database itself (it reads the record to serve
        consoles and to be ready; any write of it fails there)."""
        lease = self._lease
        if lease is not None:
            leases.fence(session, lease)
        elif self._released:
            # released at a graceful stop: what is still queued is the next ground's to
            # recover from the vehicle, refused here at once rather than one by one
            raise LeaseLost(
                f"this ground ({self.policy.holder!r}) stopped and released the command lease "
                f"{self.policy.name!r}; the transaction was refused"
            )
        elif session.get_bind().dialect.name == "sqlite":
            # no standby on SQLite (one ground a file): not yet, or no longer, the holder
            raise LeaseLost(
                f"this ground ({self.policy.holder!r}) does not hold the command lease "
                f"{self.policy.name!r}; the transaction was refused"
            )
        else:
            session.connection().exec_driver_sql("SET TRANSACTION READ ONLY")

    # -- the keeper ----------------------------------------------------------------------

    def try_acquire(self) -> bool:
        """One attempt (blocking: at the start, then from the keeper's thread)."""
        began = self._monotonic()
        try:
            with self._sessions() as session:
                got = leases.acquire(
                    session, self.policy.name, self.policy.holder, self.policy.ttl_s,
                    force=self.policy.exclusive,
                )  # fmt: skip
                session.commit()
        except Exception as exc:
            self._unreachable(exc)
            return False
        self.database_reachable = True
        if isinstance(got, LeaseRow):
            self._seen = got
            return False
        with self._guard:
            self._lease = got
            self._valid_until = began + self.policy.ttl_s - self.policy.renew_s
        self.acquisitions += 1
        log.info(
            "command lease %r acquired (token %d): this ground commands",
            got.name,
            got.token,
            extra={"fields": {"event": "lease_acquired", "token": got.token}},
        )
        return True

    def stop_commanding(self) -> None:
        """The service stops (SIGTERM): nothing more goes up, no start or abort is taken,
        and the vehicle's link is refused in the handshake (it goes to the next ground);
        the lease is kept until the last write (:meth:`close`)."""
        self._stopping = True

    def settled(self) -> None:
        """A takeover's first steps are done (``on_acquired`` calls it): the vehicle's link
        and the operators' starts are taken from now on."""
        self._settling = False

    def start(self, *, on_acquired: Callback, on_lost: LostCallback) -> None:
        """Keep the lease from a thread; ``on_acquired`` (a standby that took it over) and
        ``on_lost`` (a holder whose lease was taken) run on the calling event loop, one at
        a time."""
        self._loop = asyncio.get_running_loop()
        self._serial = asyncio.Lock()
        self._on_acquired, self._on_lost = on_acquired, on_lost
        self._thread = threading.Thread(target=self._keep, name="command-lease", daemon=True)
        self._thread.start()

    def _keep(self) -> None:
        while not self._stop.wait(self.policy.renew_s):
            if self._lease is not None and self.policy.exclusive:
                continue  # the file lock is the authority: nothing to renew
            if self._lease is None:
                self._settling = True  # before the lease is ours: no link slips in between
                if self.try_acquire():
                    self._call(self._on_acquired)
                else:
                    self._settling = False
                continue
            self._renew()

    def _renew(self) -> None:
        lease, began = self._lease, self._monotonic()
        if lease is None:
            return
        try:
            with self._sessions() as session:
                renewed = leases.renew(session, lease, self.policy.ttl_s)
                session.commit()
        except Exception as exc:
            self.renewal_failures += 1
            self._unreachable(exc)
            return
        self.database_reachable = True
        if renewed is not None:
            with self._guard:
                if self._lease is lease:
                    self._lease = renewed
                    self._valid_until = began + self.policy.ttl_s - self.policy.renew_s
            return
        with self._guard:
            self._lease = None
            self._valid_until = 0.0
        self.losses += 1
        reason = (
            f"another ground took the command lease {lease.name!r} (this ground's token "
            f"{lease.token} is stale): standing down"
        )
        log.warning(reason, extra={"fields": {"event": "lease_lost", "token": lease.token}})
        self._call(self._on_lost, reason)

    def _unreachable(self, exc: Exception) -> None:
        if self.database_reachable:
            log.warning(
                "command lease: the database does not answer (%s)%s",
                type(exc).__name__,
                "; commanding until the lease lapses" if self._lease is not None else "",
                extra={"fields": {"event": "lease_database_unreachable"}},
            )
        self.database_reachable = False

    def _call(self, callback: Callable[..., Awaitable[None]] | None, *args: Any) -> None:
        """Run ``callback`` on the service's loop, after any still running (a recovery and
        a stand-down never overlap); the keeper goes on renewing meanwhile."""
        loop = self._loop
        if callback is None or loop is None or loop.is_closed():
            return
        with contextlib.suppress(RuntimeError):  # the loop closed meanwhile
            asyncio.run_coroutine_threadsafe(self._in_turn(callback, *args), loop)

    async def _in_turn(self, callback: Callable[..., Awaitable[None]], *args: Any) -> None:
        assert self._serial is not None
        async with self._serial:
            try:
                await callback(*args)
            except Exception:
                log.exception("command lease: %s failed", getattr(callback, "__name__", "a step"))

    async def close(self) -> None:
        """Stop keeping the lease, and give it up (a graceful stop: after the last write of
        the command path), so that a standby takes over at once."""
        self._stop.set()
        if self._thread is not None:
            await asyncio.to_thread(self._thread.join)
        lease = self._lease
        if lease is None:
            return
        with self._guard:
            self._lease = None
            self._valid_until = 0.0
            self._released = True

        def give_up() -> bool:
            with self._sessions() as session:
                done = leases.release(session, lease)
                session.commit()
                return done

        try:
            released = await asyncio.to_thread(give_up)
        except Exception as exc:
            log.warning("command lease not released (%s): it expires by itself", exc)
            return
        if released:
            log.info("command lease %r released (token %d)", lease.name, lease.token)
