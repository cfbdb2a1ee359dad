"""Helpers for tests that run ROS 2 node processes (``sm-bt sim-nodes``) and talk to them.

The test session has prepared the environment (conftest: local discovery, a domain id of its own),
and the processes inherit it. Rules these helpers enforce, because each hazard was seen here:
every process is stopped by its own PID with SIGINT, then SIGKILL after 3 s (Fast DDS can hang on
exit); every ROS call has a timeout (a dead server never answers); the test side spins its executor
in a background thread and waits on futures with events (never ``spin_until_future_complete``).
"""

from __future__ import annotations

import atexit
import collections
import contextlib
import math
import os
import re
import signal
import subprocess
import threading
import time
import weakref
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import IO, Any

import pytest

from sm_bt.ros.node_process import READY_TIMEOUT, NodesError, NodesProcess
from sm_bt.ros.node_process import ManagerProcess as LibraryManagerProcess

DISCOVERY_TIMEOUT = 10.0
DISCOVERY_POLL = 0.02
#: The first call after discovery takes about 0.1 s (the response path matches late).
FIRST_CALL_TIMEOUT = 2.0
#: Seconds a new client waits before its first request that must not be asked twice.
RESPONSE_PATH_GRACE = 0.3
#: Services that may be asked twice with no other effect (see :meth:`RosContext.call`).
IDEMPOTENT = frozenset({"GetState", "GetMode", "GetAvailableModes", "GetAvailableStates", "GetAvailableTransitions",
                        "GetParameters", "ListParameters", "SetParameters", "SetParametersAtomically"})
SHM = Path("/dev/shm")
#: The environment of a node process a test kills with SIGKILL and waits to see leave the ROS graph:
#: a lease of 2 s instead of Fast DDS's 20 s (short_lease.xml), the same verdict 18 s sooner.
SHORT_LEASE = {"FASTRTPS_DEFAULT_PROFILES_FILE": str(Path(__file__).with_name("short_lease.xml"))}


class NodeProcess(NodesProcess):
    """A :class:`~sm_bt.ros.node_process.NodesProcess` that the session's shared-memory cleanup
    knows about; a failed start is a test failure with the child's whole stderr."""

    def start(self) -> NodeProcess:
        _processes.add(self)
        try:
            super().start()
        except NodesError as error:
            raise AssertionError(str(error)) from None
        return self


# -- Fast DDS shared-memory files ---------------------------------------------------------------------

_SHM_PATTERNS = ("fastrtps_*", "sem.fastrtps_*")


def shm_files() -> set[Path]:
    """The Fast DDS shared-memory files now in /dev/shm."""
    if not SHM.is_dir():
        return set()
    return {path for pattern in _SHM_PATTERNS for path in SHM.glob(pattern)}


def shm_files_in_use(*, except_pid: int | None = None) -> set[Path]:
    """Files in /dev/shm some process (of any run on this machine we can see) has mapped or open."""
    used: set[Path] = set()
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or entry.name == str(except_pid):
            continue
        try:
            for line in (entry / "maps").read_text().splitlines():
                if "/dev/shm/" in line:
                    used.add(Path(line[line.index("/dev/shm/"):].split(" (deleted)")[0]))
            for fd in (entry / "fd").iterdir():
                target = os.readlink(fd)
                if target.startswith("/dev/shm/"):
                    used.add(Path(target))
        except OSError:  # gone meanwhile, or not ours to read
            continue
    return used


#: Recorded when this module is first imported (by conftest or a test module): files older than the
#: session are somebody else's and are never removed.
SHM_AT_SESSION_START = shm_files()
#: Seconds a Fast DDS file must have existed before it may be taken for stale.
SHM_SETTLE = 5.0
_live_contexts = 0
_live_lock = threading.Lock()
#: Every process started by this session (stopped ones included): the clean-up waits for all of them.
_processes: weakref.WeakSet[NodeProcess] = weakref.WeakSet()


def _mtime(path: Path) -> float:
    try:
        return path.stat().st_mtime
    except OSError:  # removed meanwhile
        return math.inf


def remove_stale_shm_files(*, at_exit: bool = False) -> list[Path]:
    """Remove the Fast DDS files this session created that no process uses any more.

    Fast DDS leaves them behind after kills (and some even after clean exits). Does nothing while
    one of our processes or a test-side context is alive, nor in a pytest-xdist worker (the
    controller, which starts no ROS process, removes what the workers left when it exits); files of
    parallel runs are still mapped by their processes and are kept, and so is any file younger than
    :data:`SHM_SETTLE` (its process may not have mapped it yet). This process keeps its own port files
    mapped until it exits, so ``at_exit`` (the interpreter is ending) also removes those.
    """
    if os.environ.get("PYTEST_XDIST_WORKER"):
        return []  # other workers' processes come and go meanwhile: the controller removes them at its exit
    with _live_lock:
        if _live_contexts or any(process.alive for process in list(_processes)):
            return []
    # A file made in the last moments may belong to a process of a parallel worker that has not mapped
    # it yet: it is not "in use" for that instant, and removing it would cut that process off.
    young = time.time() - SHM_SETTLE
    stale = {path for path in shm_files() - SHM_AT_SESSION_START if _mtime(path) < young}
    if not stale:
        return []
    stale -= shm_files_in_use(except_pid=os.getpid() if at_exit else None)
    removed = []
    for path in sorted(stale):
        try:
            path.unlink()
            removed.append(path)
        except OSError:
            pass
    return removed


atexit.register(remove_stale_shm_files, at_exit=True)

Starter = Callable[..., NodeProcess]


@pytest.fixture(name="node_processes")
def node_processes_fixture() -> Iterator[Starter]:
    """``start(model, *args) -> NodeProcess`` (READY already seen); every process started is stopped
    by PID at teardown, then the session's stale Fast DDS files are removed."""
    started: list[NodeProcess] = []

    def start(model: str, *args: str, ready_timeout: float = READY_TIMEOUT,
              env: dict[str, str] | None = None) -> NodeProcess:
        process = NodeProcess(model, *args, ready_timeout=ready_timeout, env=env)
        started.append(process)  # before start(): a process that never gets READY is stopped too
        return process.start()

    yield start
    for process in started:
        process.stop()
    remove_stale_shm_files()  # does nothing while a process of the session or a test context lives


# -- the test process's side -------------------------------------------------------------------------


class RosContext:
    """A fresh rclpy context with one node, its executor spinning in a daemon thread."""

    def __init__(self, name: str = "sm_bt_test") -> None:
        global _live_contexts
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions

        with _live_lock:
            _live_contexts += 1
        self.context = Context()
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        self.node: Any = rclpy.create_node(name, context=self.context)
        self._clients: dict[tuple[Any, str], Any] = {}
        self._answered: set[Any] = set()  # clients that got an answer once
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self._spin, name="ros-test-spin", daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        from rclpy.executors import ExternalShutdownException

        with contextlib.suppress(ExternalShutdownException):  # the context was shut down under us
            self.executor.spin()

    def client(self, service_type: Any, name: str) -> Any:
        """The client of service ``name`` (one per name: a new client would need discovery again)."""
        key = (service_type, name)
        if key not in self._clients:
            self._clients[key] = self.node.create_client(service_type, name)
        return self._clients[key]

    def call(self, service_type: Any, name: str, request: Any, timeout: float = FIRST_CALL_TIMEOUT) -> Any:
        """Call service ``name`` (waiting for its discovery first) and return the response.

        The first request of a fresh client can go unanswered: the server answers before the
        path back to this client is matched (DDS discovery; seen on a loaded machine, never on a
        quiet one), and a real client asks again. So does this one, once, for a query or a
        parameter set (asking twice changes nothing); a transition is never asked twice."""
        client = self.client(service_type, name)
        if not client.service_is_ready():
            self.wait_for([client])
        first = client not in self._answered
        if first and service_type.__name__ not in IDEMPOTENT:
            # Asked once only: give the server's side of discovery (its answer's path to this new
            # client) a moment, which the client cannot see (a fresh-clone run lost an activate so).
            time.sleep(RESPONSE_PATH_GRACE)
        try:
            response = call(client, request, timeout)
        except AssertionError:
            if not first or service_type.__name__ not in IDEMPOTENT:
                raise
            response = call(client, request, timeout)
        self._answered.add(client)
        return response

    def subscribe(self, message_type: Any, topic: str, depth: int = 50) -> list[Any]:
        """A list the messages on ``topic`` are appended to (by the executor thread)."""
        received: list[Any] = []
        self.node.create_subscription(message_type, topic, received.append, depth)
        return received

    def wait_for(self, clients: Sequence[Any], timeout: float = DISCOVERY_TIMEOUT) -> float:
        """Poll ``service_is_ready()`` every 20 ms until all are; returns the seconds it took."""
        start = time.monotonic()
        while True:
            missing = [client.srv_name for client in clients if not client.service_is_ready()]
            if not missing:
                return time.monotonic() - start
            if time.monotonic() - start > timeout:
                raise AssertionError(f"services not discovered after {timeout:.0f} s: {', '.join(missing)}")
            time.sleep(DISCOVERY_POLL)

    def close(self) -> None:
        global _live_contexts
        self.executor.shutdown(timeout_sec=2.0)
        self.thread.join(timeout=3.0)
        self.node.destroy_node()
        self.context.try_shutdown()
        with _live_lock:
            _live_contexts -= 1
        remove_stale_shm_files()


@pytest.fixture(name="ros_context")
def ros_context_fixture() -> Iterator[RosContext]:
    """A :class:`RosContext` per test, shut down at teardown (executor, thread, node, context)."""
    ros = RosContext()
    try:
        yield ros
    finally:
        ros.close()


def call(client: Any, request: Any, timeout: float = 1.0) -> Any:
    """The response of ``client`` to ``request`` (the executor spins elsewhere: ``answer``);
    ``AssertionError`` after ``timeout`` seconds."""
    from sm_bt.ros.node_calls import answer

    try:
        response = answer(client, request, timeout)
    except Exception as error:
        raise AssertionError(f"{client.srv_name}: call failed: {error!r}") from error
    if response is None:
        raise AssertionError(f"{client.srv_name}: no response within {timeout} s to {request}")
    return response


def wait_until(condition: Callable[[], bool], timeout: float, message: str, poll: float = 0.01) -> float:
    """Poll ``condition`` until true; the seconds it took, or ``AssertionError(message)``."""
    start = time.monotonic()
    while not condition():
        if time.monotonic() - start > timeout:
            raise AssertionError(f"{message} (after {timeout} s)")
        time.sleep(poll)
    return time.monotonic() - start


#: A log line in ROS 2's console format: ``[SEVERITY] [seconds.micro] [logger]: message`` (rclpy's
#: own lines have nanoseconds).
LOG_LINE = re.compile(r"^\[(DEBUG|INFO|WARN|ERROR|FATAL)\] \[\d+\.\d{6}(?:\d{3})?\] \[([\w.]+)\]: (.*)$")


# -- the manager's process -----------------------------------------------------------------------------


class ManagerProcess(NodeProcess, LibraryManagerProcess):
    """``python -m sm_bt.cli manager MODEL ARGS...`` (the library's, with the tests' start): ready once it
    says what it serves; stopped by PID like every ROS process of the tests (SIGINT, then SIGKILL); its
    stderr is kept whole."""

    def __init__(self, model: str, *args: str) -> None:
        super().__init__(model, *args)
        self._stderr = collections.deque(maxlen=20_000)
        self._starter: threading.Thread | None = None
        self._failure: BaseException | None = None

    def launch(self) -> ManagerProcess:
        """:meth:`start` in a background thread, so that the node processes start meanwhile;
        :meth:`ready` waits for it."""

        def run() -> None:
            try:
                self.start()
            except BaseException as failure:  # re-raised by ready()
                self._failure = failure

        self._starter = threading.Thread(target=run, name="manager-start", daemon=True)
        self._starter.start()
        return self

    def ready(self) -> ManagerProcess:
        """Wait until it is serving; the start's failure (with its stderr) otherwise."""
        self.join_starter()
        if self._failure is not None:
            raise self._failure
        return self

    def join_starter(self) -> None:
        if self._starter is not None:
            self._starter.join(READY_TIMEOUT + 10.0)

    def log(self) -> list[tuple[str, str, str]]:
        """(severity, logger, message) of every log line on stderr so far."""
        matches = [LOG_LINE.match(line) for line in list(self._stderr)]
        return [(m.group(1), m.group(2), m.group(3)) for m in matches if m is not None]

    def lines(self, *words: str, severities: tuple[str, ...] = ()) -> list[str]:
        """The messages of the log lines that contain every one of ``words`` (case-insensitive)."""
        return [message for severity, _, message in self.log()
                if all(word.lower() in message.lower() for word in words)
                and (not severities or severity in severities)]


@pytest.fixture(name="start_manager")
def start_manager_fixture() -> Iterator[Callable[..., ManagerProcess]]:
    """``start(*args, model="pilot")``: ``sm-bt manager MODEL ARGS`` starting (call ``ready()`` on
    it before use); stopped at teardown, once its start is over (it cannot escape the stop)."""
    started: list[ManagerProcess] = []

    def start(*args: str, model: str = "pilot") -> ManagerProcess:
        process = ManagerProcess(model, *args)
        started.append(process)
        return process.launch()

    yield start
    for process in started:
        process.join_starter()
        process.stop()
    remove_stale_shm_files()


#: Environment for a process a test may have to diagnose: SIGABRT prints every thread's stack.
DUMPABLE = {"PYTHONFAULTHANDLER": "1"}


def communicate_or_dump(process: subprocess.Popen[str], timeout: float) -> tuple[str, str]:
    """``process.communicate(timeout)``; if it does not end in time, its threads' stacks (it was
    started with :data:`DUMPABLE`: SIGABRT makes faulthandler print them) go into the failure."""
    try:
        out, err = process.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        process.send_signal(signal.SIGABRT)
        try:
            _, err = process.communicate(timeout=5.0)
        except subprocess.TimeoutExpired:
            process.kill()
            _, err = process.communicate(timeout=5.0)
        raise AssertionError(f"still running {timeout:g} s later; its threads were:\n{err[-6000:]}") from None
    return out, err


def line_within(stream: IO[str] | None, timeout: float, what: str) -> str:
    """The next line of a child's ``stream`` (``""`` at its end), or ``AssertionError(what)`` after
    ``timeout`` s: a child that stalls before its line fails the test instead of holding it up (the
    read goes on in a thread until the child is stopped)."""
    assert stream is not None
    got: list[str] = []
    reader = threading.Thread(target=lambda: got.append(stream.readline()), name="line-within", daemon=True)
    reader.start()
    reader.join(timeout)
    if not got:
        raise AssertionError(f"{what}: no line within {timeout:g} s")
    return got[0]


class Starved:
    """How long this process went without running while in the block: a thread that sleeps 10 ms at
    a time keeps the worst oversleep. On a machine so loaded that a process waited that long for a
    core, a bound of the manager's own can only hold that much later (measured here, in the
    manager's process or beside it: what the machine's load did to a process)."""

    def __init__(self) -> None:
        self.worst = 0.0
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._watch, name="starved", daemon=True)

    def _watch(self) -> None:
        while not self._done.is_set():
            asked = time.monotonic()
            time.sleep(0.01)
            self.worst = max(self.worst, time.monotonic() - asked - 0.01)

    def __enter__(self) -> Starved:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._done.set()
        self._thread.join(1.0)
