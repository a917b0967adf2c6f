"""Shared fixtures."""

from __future__ import annotations

import contextlib
import os
import pickle
import shutil
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from planner.dynamics import DynamicsWorkspace
from planner.model import RobotModel, default_model
from planner.schedule import plan_pass
from spacecraft.offline import fly_offline
from telemetry.recording import PassRecording
from tests.support.made_once import MadeOnce
from tests.support.processes import flocked

# No test (nor a server it starts) reads a developer's ./.env or /run/secrets: every
# setting a test wants it passes itself (server/settings.py).
os.environ["HIKOBOSHI_ENV_FILE"] = os.devnull
os.environ["HIKOBOSHI_SECRETS_DIR"] = os.devnull


@pytest.fixture(scope="session")
def model() -> RobotModel:
    return default_model()


@pytest.fixture()
def workspace(model: RobotModel) -> DynamicsWorkspace:
    return DynamicsWorkspace(model)


@pytest.fixture(scope="session")
def demo_recording(made_once: MadeOnce) -> PassRecording:
    """A flown demo pass (the whole ETS-VII schedule through the real vehicle, default
    sensor noise and gravity gradient, perfect link), shared by the post-pass tests of a
    run (telemetry and server): about 17 s to plan and fly, once for all the workers (a
    pickle in the run's shared folder: our own objects, written and read by this run)."""

    def make(folder: Path) -> None:
        plan = plan_pass(DynamicsWorkspace(default_model()))
        flight = fly_offline(plan, seed=7)
        recording = PassRecording.from_frames(
            "demo", plan, flight.epoch_ns, flight.frames, meta={"source": "offline flight, seed 7"}
        )
        (folder / "demo.pickle").write_bytes(pickle.dumps((flight.rejected, recording)))

    rejected, recording = pickle.loads(
        (made_once("demo-recording", make) / "demo.pickle").read_bytes()
    )
    assert not rejected, rejected[:3]
    assert isinstance(recording, PassRecording)
    return recording


@pytest.fixture(scope="session")
def demo_mcap_file(made_once: MadeOnce, demo_recording: PassRecording) -> Path:
    """``demo_recording`` written by ``write_mcap`` (a 17 MB file, seconds to write), once
    per run for the MCAP tests and the report tests that upload it: read only."""
    from telemetry.mcap import write_mcap

    def make(folder: Path) -> None:
        write_mcap(demo_recording, folder / "demo.mcap")

    return made_once("demo-mcap", make) / "demo.mcap"


#: The PostgreSQL fixtures, for every directory (tests/postgres.py).
pytest_plugins = ("tests.postgres",)


#: Tests that fly a vehicle or serve a live link in wall time (a spacecraft process, a
#: server with its link, a browser on a live pass, the console hub's pacing) are marked
#: ``realtime`` (a module's ``pytestmark`` or the test's own mark): their margins are onboard
#: seconds divided by the time scale, tens of milliseconds of wall at 10x. They run one at a
#: time across the workers (a ``flock`` held from setup to teardown), beside at most one test
#: of the other kind: the one busy core they are written for. Two of them side by side on a
#: slow machine starved each other (the 200-viewer load beside the live console). (xdist's
#: ``loadgroup`` would put them on one worker, but xdist 3.8 cannot rename the node ids of
#: pytest 9.)


def _realtime(item: pytest.Item) -> bool:
    return item.get_closest_marker("realtime") is not None


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Modules with a slow test run first, each module's tests in their own order: with the
    suite spread over workers (pyproject's ``-n``), a minute-long test started last keeps one
    worker busy after the other has run out of work. Within that, the real-time tests come
    first: xdist's worksteal hands the first half of the list to one worker and the second
    to the other, so one worker starts on the real-time tests and the other on the rest."""
    slow = {item.path for item in items if item.get_closest_marker("slow") is not None}
    items.sort(key=lambda item: (not _realtime(item), item.path not in slow))  # stable


def _run_folder(run_id: str) -> Path:
    """The folder the xdist workers of one run share (named by the run's id)."""
    folder = Path(tempfile.gettempdir()) / f"hikoboshi-tests-{run_id}"
    folder.mkdir(exist_ok=True)
    return folder


_RUN_ID = os.environ.get("PYTEST_XDIST_TESTRUNUID")  # set in xdist's workers only
#: The lock file each ``realtime`` test holds from its setup to its teardown (an exclusive
#: ``flock`` shared by the run's xdist workers).
_REALTIME = _run_folder(_RUN_ID) / "realtime.lock" if _RUN_ID else None


@pytest.fixture(scope="session")
def made_once(tmp_path_factory: pytest.TempPathFactory) -> MadeOnce:
    """Made once per test run and shared: across xdist's workers the folder is in the run's
    shared folder and the first worker to ask makes it holding an exclusive ``flock`` (the
    others wait on it, then read what it made); without xdist, once per session in its
    temporary folder. Readers must not change it: one that must copies it first. A ``make``
    that raises leaves it unmade (the next to ask starts again in an emptied folder), so a
    costly one should record a failure (an exit status, a stderr) for its readers to assert
    on rather than raise."""
    base = _run_folder(_RUN_ID) if _RUN_ID else tmp_path_factory.mktemp("made-once")

    def made(name: str, make: Callable[[Path], None]) -> Path:
        folder, done = base / name, base / f"{name}.done"
        with flocked(base / f"{name}.lock"):
            if not done.exists():
                shutil.rmtree(folder, ignore_errors=True)
                folder.mkdir()
                make(folder)
                done.touch()
        return folder

    return made


#: ``HIKOBOSHI_TEST_TIMELINE=path``: each test's wall start and end, its worker and outcome
#: appended to that file (what ran beside what, when a run on a loaded machine fails).
TIMELINE = os.environ.get("HIKOBOSHI_TEST_TIMELINE")


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item) -> Iterator[None]:
    """A ``realtime`` test holds the real-time lock from setup to teardown; each test's
    times go to the timeline."""
    held = flocked(_REALTIME) if _REALTIME is not None and _realtime(item) else None
    with held or contextlib.nullcontext():
        start = time.time()
        yield
    if TIMELINE:
        worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
        with open(TIMELINE, "a") as out:
            out.write(f"{start:.1f} {time.time():.1f} {worker} {item.nodeid}\n")


# --- no test leaves a thread or a process of ours behind --------------------------------------

#: Threads our code and our test harnesses name; one still alive after its test is a leak
#: (a database worker nobody closed, a server nobody stopped).
OUR_THREADS = ("ground-db", "ground", "uvicorn", "uvicorn-edge", "spacecraft")
#: How long a test's threads and processes get to end after its teardown (the OS reaps
#: children asynchronously; a loaded machine is slow to schedule a thread's last steps).
LEAK_GRACE_S = 10.0


def _our_threads() -> set[threading.Thread]:
    # Not the default executors' ``asyncio_N`` threads: the browser driver's and the test
    # clients' loops keep theirs for their fixtures' lifetime. The lifespan's own executor
    # is checked where it is made (tests/server/api/test_app.py).
    return {t for t in threading.enumerate() if t.name in OUR_THREADS and t.is_alive()}


@pytest.fixture(scope="session", autouse=True)
def _no_thread_outlives_the_run() -> Iterator[None]:
    """Nothing of ours is alive once every test and fixture of the run is done (the check
    after each test leaves out what was already running before it: a module- or
    session-scoped fixture's database worker would go unseen)."""
    yield
    deadline = time.monotonic() + LEAK_GRACE_S
    for thread in _our_threads():
        thread.join(max(0.0, deadline - time.monotonic()))
    left = sorted(t.name for t in _our_threads())
    assert not left, f"threads alive at the end of the run: {left}"


#: Children that live as long as the interpreter: multiprocessing's forkserver and its
#: resource tracker, one each, shared by every worker pool of the process; not a test's.
LIFELONG_CHILDREN = (b"multiprocessing.forkserver", b"multiprocessing.resource_tracker")


def _children() -> dict[int, str]:
    """This process's live child processes (not zombies) but the lifelong ones, with their
    command lines."""
    me = str(os.getpid())
    found: dict[int, str] = {}
    for entry in os.scandir("/proc"):
        if not entry.name.isdigit():
            continue
        try:
            stat = Path(entry.path, "stat").read_text()
            cmdline = Path(entry.path, "cmdline").read_bytes()
        except OSError:
            continue
        state, parent = stat.rsplit(")", 1)[-1].split()[:2]
        if parent == me and state != "Z" and not any(k in cmdline for k in LIFELONG_CHILDREN):
            found[int(entry.name)] = cmdline.replace(b"\0", b" ").decode(errors="replace")[:200]
    return found


@pytest.fixture(autouse=True)
def _no_leaked_threads_or_processes() -> Iterator[None]:
    """Every test ends its own database workers, servers and child processes (autouse: torn
    down after the test's other function fixtures)."""
    threads, children = _our_threads(), _children()
    yield
    deadline = time.monotonic() + LEAK_GRACE_S
    for thread in _our_threads() - threads:
        thread.join(max(0.0, deadline - time.monotonic()))
    left = _our_threads() - threads
    extra = _children().keys() - children.keys()
    while extra and time.monotonic() < deadline:
        time.sleep(0.05)
        extra = _children().keys() - children.keys()
    assert not left, f"threads left running by the test: {sorted(t.name for t in left)}"
    left_children = {pid: cmd for pid, cmd in _children().items() if pid in extra}
    assert not left_children, f"child processes left running by the test: {left_children}"
