"""A child process running simulated nodes (``sm-bt sim-nodes``) or a manager (``sm-bt manager``),
started and stopped safely.

Used by ``sm-bt demo --ros`` (and ``--fleet --ros``), the benchmarks and the tests.
:meth:`NodesProcess.start` waits for the child's ``READY`` line (a manager's: the line that says
what it serves); its output is read by threads (a full pipe would block the child). Stopping is
always by the child's own PID: SIGINT, a grace period, then SIGKILL, because Fast DDS can (rarely)
hang on exit. The child inherits this process's environment, so prepare the ROS environment
(:func:`sm_bt.ros.environment.prepare`) first.
"""

from __future__ import annotations

import collections
import math
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType
from typing import IO

from sm_bt.model.errors import Error

READY_TIMEOUT = 20.0  # the child starts rclpy and its nodes: a few seconds on a loaded machine
STOP_GRACE = 3.0  # SIGINT, then SIGKILL after this long
KEPT_LINES = 400  # of each output stream, for error messages and tests


def stop_process(process: subprocess.Popen[str], grace: float = STOP_GRACE) -> int | None:
    """Stop a ROS process we started: SIGINT to its PID, wait up to ``grace`` s, then SIGKILL (Fast
    DDS can hang on exit); its exit code (negative: killed). Nothing if it has ended already."""
    if process.poll() is None:
        process.send_signal(signal.SIGINT)
        try:
            process.wait(grace)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(5.0)
    return process.returncode


@contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """While it is entered, SIGTERM unwinds like Ctrl-C (in the main thread), so that the child
    processes started meanwhile are still stopped."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum: int, frame: FrameType | None) -> None:
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


class NodesError(Error, RuntimeError):
    """The node process did not start or stopped (the message says how, with its stderr)."""


class NodesProcess:
    """``sm-bt sim-nodes MODEL ARGS...`` (``python -m sm_bt.cli sim-nodes``) as a child process."""

    def __init__(self, model: str, *args: str, ready_timeout: float = READY_TIMEOUT,
                 env: dict[str, str] | None = None) -> None:
        self.command = [sys.executable, "-m", "sm_bt.cli", "sim-nodes", model, *args]
        self.ready_timeout = ready_timeout
        #: Variables set for the child on top of this process's environment.
        self.env = dict(env or {})
        self.process: subprocess.Popen[str] | None = None
        #: The fully qualified names of its nodes, from the READY line.
        self.names: list[str] = []
        #: Seconds from start to READY.
        self.ready_after = math.nan
        self._stdout: collections.deque[str] = collections.deque(maxlen=KEPT_LINES)
        self._stderr: collections.deque[str] = collections.deque(maxlen=KEPT_LINES)
        self._ready = threading.Event()
        self._readers: list[threading.Thread] = []

    # -- life of the process -------------------------------------------------------------------------

    def start(self) -> NodesProcess:
        """Start it and wait for ``READY``; :class:`NodesError` (after stopping it) otherwise."""
        self._stdout.clear()
        self._stderr.clear()
        self.names = []
        self._ready = threading.Event()
        started = time.monotonic()
        self.process = subprocess.Popen(self.command, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                        stderr=subprocess.PIPE, text=True, bufsize=1,
                                        env={**os.environ, **self.env} if self.env else None)
        self._readers = [
            threading.Thread(target=self._read, args=(self.process.stdout, self._stdout, True),
                             name="sim-nodes-stdout", daemon=True),
            threading.Thread(target=self._read, args=(self.process.stderr, self._stderr, False),
                             name="sim-nodes-stderr", daemon=True),
        ]
        for reader in self._readers:
            reader.start()
        while not self._ready.wait(0.05):
            if self.process.poll() is not None or time.monotonic() - started > self.ready_timeout:
                how = (f"exited with code {self.process.returncode}" if self.process.poll() is not None
                       else f"not READY after {self.ready_timeout:.0f} s")
                self.stop()
                for reader in self._readers:  # the whole of stderr, up to the exit
                    reader.join(1.0)
                raise NodesError(f"{' '.join(self.command[1:])}: {how}" + self._stderr_suffix())
        self.ready_after = time.monotonic() - started
        return self

    def stop(self, grace: float = STOP_GRACE) -> int | None:
        """SIGINT to its PID, wait up to ``grace`` s, then SIGKILL; the exit code (negative: killed).
        Idempotent."""
        return None if self.process is None else stop_process(self.process, grace)

    def kill(self) -> None:
        """SIGKILL now (a crash). Peers keep seeing its services for the DDS lease (about 20 s)."""
        if self.process is not None and self.process.poll() is None:
            self.process.kill()
            self.process.wait(5.0)

    def restart(self) -> NodesProcess:
        """Stop it (SIGINT, then SIGKILL) and start it again with the same arguments."""
        self.stop()
        return self.start()

    def check(self) -> None:
        """:class:`NodesError` if the process has exited."""
        if self.process is not None and self.process.poll() is not None:
            raise NodesError(f"the node process (pid {self.process.pid}) exited with code "
                             f"{self.process.returncode}" + self._stderr_suffix())

    # -- what it said --------------------------------------------------------------------------------

    @property
    def pid(self) -> int | None:
        return None if self.process is None else self.process.pid

    @property
    def alive(self) -> bool:
        return self.process is not None and self.process.poll() is None

    @property
    def returncode(self) -> int | None:
        return None if self.process is None else self.process.poll()

    @property
    def stdout(self) -> str:
        return "\n".join(self._stdout)

    @property
    def stderr(self) -> str:
        return "\n".join(self._stderr)

    def _read(self, stream: IO[str], lines: collections.deque[str], watch_ready: bool) -> None:
        for line in stream:
            lines.append(line.rstrip("\n"))
            if watch_ready and line.startswith("READY "):
                self.names = [name for name in line[len("READY "):].strip().split(",") if name]
                self._ready.set()
        stream.close()

    def _stderr_suffix(self) -> str:
        return f"\nits stderr:\n{self.stderr}" if self._stderr else ""


class ManagerProcess(NodesProcess):
    """``sm-bt manager MODEL ARGS...`` as a child process: ready once it says what it serves."""

    def __init__(self, model: str, *args: str, ready_timeout: float = READY_TIMEOUT,
                 env: dict[str, str] | None = None) -> None:
        super().__init__(model, ready_timeout=ready_timeout, env=env)
        self.command = [sys.executable, "-m", "sm_bt.cli", "manager", model, *args]

    def _read(self, stream: IO[str], lines: collections.deque[str], watch_ready: bool) -> None:
        for line in stream:
            lines.append(line.rstrip("\n"))
            if watch_ready and line.startswith("mode manager "):
                self._ready.set()
        stream.close()
