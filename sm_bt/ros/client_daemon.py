"""The client daemon: one long-lived process that keeps watching the ROS graph for ``sm-bt mode``
and ``sm-bt state``, so that a command finds a known manager at once.

A fresh process needs DDS discovery before it can call the manager, and that took from under
0.2 s to 3 s here (docs/cli.md); ``ros2`` has its daemon for the same reason. The daemon serves a
Unix socket, one per user and ROS setting (:func:`socket_path`): a command connects, and each of
its calls to :class:`~sm_bt.ros.client.ModeClient` runs in the daemon, on a node of its own in the
daemon's context, whose graph is already known. The protocol is one JSON object per line:

* the command's first line: ``{"fingerprint": F, "do": "client", "timeout": T}`` (or ``"do":
  "status"`` / ``"stop"``), answered with ``{"ok": true}`` or ``{"refused": reason}`` (a daemon of
  other code: the caller goes on without it and the daemon exits);
* then per call ``{"call": NAME, "args": [...]}``, answered with ``{"value": V, "sent": S}`` or
  ``{"raise": CLASS, "message": M, "sent": S}``; ``sent`` is ``time.monotonic()``, which is one
  clock for every process of the machine.

The daemon exits after ``idle`` seconds without a connection. This module imports no rclpy until
:func:`serve` runs, so a command that reaches the daemon starts in a quarter of a second.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import logging
import os
import socket
import socketserver
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TextIO

from sm_bt.model.errors import Error
from sm_bt.ros import client as client_module

log = logging.getLogger(__name__)

#: The settings that decide which graph a process sees: a daemon serves one combination.
GRAPH_SETTINGS = ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_STATIC_PEERS", "ROS_LOCALHOST_ONLY",
                  "RMW_IMPLEMENTATION", "ROS_DISCOVERY_SERVER", "FASTRTPS_DEFAULT_PROFILES_FILE",
                  "FASTDDS_DEFAULT_PROFILES_FILE", "FASTDDS_BUILTIN_TRANSPORTS", "CYCLONEDDS_URI")
#: The ModeClient methods a command may call through the daemon.
CALLS = frozenset({"get_mode", "available_modes", "check_mode", "change_mode", "wait_for_mode", "get_state",
                   "change_state", "wait_for_state", "managed_node", "state_after", "preview_change",
                   "request_change", "offers", "hold_mode", "listen"})
#: The errors a call may raise, re-raised in the command as the same class.
ERRORS: dict[str, type[Exception]] = {cls.__name__: cls for cls in (
    client_module.ManagerUnreachable, client_module.UnknownName, client_module.NotConfirmed)}
#: Seconds without a connection after which the daemon exits.
DEFAULT_IDLE = 3600.0
#: How long a command waits for the daemon to accept it before going on without it.
CONNECT = 0.5
#: Commands a pooled client serves before it is replaced: rclpy's executor keeps a done task per
#: wait, and each spin walks them all (ros2-from-pypi hazards).
CLIENT_USES = 50
#: Set to 0 to never use or start the daemon (tests, or to measure a fresh process).
DISABLE_VARIABLE = "SM_BT_DAEMON"


class DaemonUnavailable(Error, RuntimeError):
    """No daemon answers (or one of other code): the command goes on without it."""


def fingerprint() -> str:
    """The code a daemon must run to serve a command: the two modules' source."""
    digest = hashlib.sha256()
    for module in (client_module.__file__, __file__):
        digest.update(Path(str(module)).read_bytes())
    return digest.hexdigest()[:16]


def socket_path() -> Path:
    """The socket of the daemon for this user, this Python and this shell's ROS settings."""
    key = json.dumps([sys.executable, *(os.environ.get(name, "") for name in GRAPH_SETTINGS)])
    base = Path(os.environ.get("XDG_RUNTIME_DIR") or tempfile.gettempdir()) / f"sm_bt-{os.getuid()}"
    return base / f"daemon-{hashlib.sha256(key.encode()).hexdigest()[:12]}.sock"


def enabled() -> bool:
    return os.environ.get(DISABLE_VARIABLE, "1") != "0"


# -- the command's side ----------------------------------------------------------------------------


class DaemonClient:
    """A :class:`~sm_bt.ros.client.ModeClient` whose calls run in the daemon (same methods, same
    errors, ``sent`` kept in step)."""

    def __init__(self, timeout: float, path: Path | None = None) -> None:
        self.timeout = timeout
        self.sent = 0.0
        self._connection, self._lines, _ = _connect(path or socket_path(), {"do": "client", "timeout": timeout})

    def __getattr__(self, name: str) -> Callable[..., Any]:
        if name not in CALLS:
            raise AttributeError(name)
        return lambda *args, **kwargs: self._call(name, list(args), kwargs)

    def _call(self, name: str, args: list[Any], kwargs: dict[str, Any]) -> Any:
        # A call ends within its own timeouts in the daemon; this bound only guards a daemon that hangs.
        self._connection.settimeout(3 * max(self.timeout, client_module.GRAPH_SETTLE, 5.0) + 5.0)
        try:
            self._connection.sendall((json.dumps({"call": name, "args": args, "kwargs": kwargs}) + "\n").encode())
            reply = json.loads(self._lines.readline() or "null")
        except (OSError, ValueError) as error:
            raise client_module.ManagerUnreachable(
                f"the sm-bt client daemon did not answer ({error}): `sm-bt daemon stop`, or set "
                f"{DISABLE_VARIABLE}=0 to do without it") from None
        if not isinstance(reply, dict):
            raise client_module.ManagerUnreachable("the sm-bt client daemon went away during the call: try again")
        self.sent = float(reply.get("sent", self.sent))
        if "raise" in reply:
            raise ERRORS.get(reply["raise"], RuntimeError)(reply["message"])
        return reply["value"]

    def close(self) -> None:
        self._lines.close()
        self._connection.close()

    def __enter__(self) -> DaemonClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _connect(path: Path, hello: dict[str, Any]) -> tuple[socket.socket, TextIO, dict[str, Any]]:
    """A connection to the daemon at ``path`` that accepted ``hello``, its lines, and its answer."""
    connection = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    connection.settimeout(CONNECT)
    lines = connection.makefile("r", encoding="utf-8")
    try:
        connection.connect(str(path))
        connection.sendall((json.dumps({"fingerprint": fingerprint(), **hello}) + "\n").encode())
        answer = json.loads(lines.readline() or "null")
    except (OSError, ValueError) as error:
        lines.close()
        connection.close()
        raise DaemonUnavailable(f"no client daemon answers at {path} ({error})") from None
    if not isinstance(answer, dict) or not answer.get("ok"):
        lines.close()
        connection.close()
        raise DaemonUnavailable(f"the client daemon at {path} refused: {answer}")
    return connection, lines, answer


def ask(do: str, path: Path | None = None) -> dict[str, Any]:
    """Ask the daemon for its ``status`` or to ``stop``: its answer; :class:`DaemonUnavailable`
    when none answers."""
    connection, lines, answer = _connect(path or socket_path(), {"do": do})
    lines.close()
    connection.close()
    return answer


def start_detached(idle: float = DEFAULT_IDLE) -> int:
    """Start the daemon for this shell's settings in the background; its pid. Its log is the
    socket's path with ``.log``."""
    path = socket_path()
    path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
    with open(path.with_suffix(".log"), "ab") as log_file:
        process = subprocess.Popen(
            [sys.executable, "-m", "sm_bt.cli", "daemon", "run", "--idle", f"{idle:g}"],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=log_file, start_new_session=True)
    return process.pid


# -- the daemon's side -----------------------------------------------------------------------------


class _Server(socketserver.ThreadingMixIn, socketserver.UnixStreamServer):
    daemon_threads = True

    def __init__(self, path: Path, context: Any, idle: float) -> None:
        self.context = context
        self.idle = idle
        self.started = time.monotonic()
        self.fingerprint = fingerprint()
        self.lock = threading.Lock()
        self.active = 0
        self.served = 0
        self.last = time.monotonic()
        # Clients kept between commands: the manager has already matched their endpoints, so a
        # request's answer cannot be lost on a path the server has not discovered yet.
        self.pool: list[tuple[Any, int]] = []
        super().__init__(str(path), _Handler)

    def checkout(self, timeout: float) -> tuple[Any, int]:
        """A client for one command (a pooled one if any is free), and how many it served before."""
        with self.lock:
            self.active += 1
            self.served += 1
            number = self.served
            if self.pool:
                mode_client, uses = self.pool.pop()
                mode_client.timeout, mode_client.sent = timeout, 0.0
                return mode_client, uses
        return client_module.ModeClient(timeout=timeout, node_name=f"sm_bt_client_{os.getpid()}_{number}",
                                        context=self.context, graph_since=self.started), 0

    def give_back(self, mode_client: Any, uses: int) -> None:
        mode_client.stop_listening()  # a command that listened and then did not wait (refused, failed)
        with self.lock:
            self.active -= 1
            self.last = time.monotonic()
            if uses < CLIENT_USES:
                self.pool.append((mode_client, uses))
                return
        mode_client.close()

    def close_pool(self) -> None:
        with self.lock:
            pool, self.pool = self.pool, []
        for mode_client, _ in pool:
            mode_client.close()

    def idle_for(self) -> float:
        with self.lock:
            return 0.0 if self.active else time.monotonic() - self.last

    def stop_soon(self) -> None:
        threading.Thread(target=self.shutdown, daemon=True).start()


class _Handler(socketserver.StreamRequestHandler):
    server: _Server

    def handle(self) -> None:
        try:
            hello = json.loads(self.rfile.readline() or "null")
        except ValueError:
            return
        if not isinstance(hello, dict):
            return
        if hello.get("fingerprint") != self.server.fingerprint:
            self._send({"refused": "this daemon runs other sm_bt code; it exits now"})
            log.warning("a command of other sm_bt code connected: exiting so that it can start its own")
            self.server.stop_soon()
            return
        if hello.get("do") == "status":
            self._send({"ok": True, "pid": os.getpid(), "uptime": time.monotonic() - self.server.started,
                        "served": self.server.served, "idle_exit": self.server.idle,
                        "settings": {name: os.environ[name] for name in GRAPH_SETTINGS if name in os.environ}})
        elif hello.get("do") == "stop":
            self._send({"ok": True, "pid": os.getpid()})
            log.info("asked to stop")
            self.server.stop_soon()
        elif hello.get("do") == "client":
            self._serve_client(float(hello.get("timeout", 10.0)))

    def _serve_client(self, timeout: float) -> None:
        mode_client, uses = self.server.checkout(timeout)
        try:
            self._send({"ok": True})
            for line in self.rfile:
                call = json.loads(line)
                name = call.get("call")
                try:
                    if name not in CALLS:
                        raise client_module.ManagerUnreachable(f"the client daemon has no call {name!r}")
                    value = getattr(mode_client, name)(*call.get("args", []), **call.get("kwargs", {}))
                    self._send({"value": value, "sent": mode_client.sent})
                except tuple(ERRORS.values()) as error:
                    self._send({"raise": type(error).__name__, "message": str(error), "sent": mode_client.sent})
        except (OSError, ValueError):
            pass  # the command went away (Ctrl-C)
        finally:
            self.server.give_back(mode_client, uses + 1)

    def _send(self, message: dict[str, Any]) -> None:
        self.wfile.write((json.dumps(message) + "\n").encode())
        self.wfile.flush()


def serve(idle: float = DEFAULT_IDLE, path: Path | None = None, ready: Callable[[Path], None] | None = None) -> int:
    """Serve commands until ``idle`` seconds pass without one, or a ``stop``; 0, or 1 when a
    daemon already serves ``path`` (this one then does nothing)."""
    import rclpy
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions

    from sm_bt.ros.environment import prepare, require_ros

    path = path or socket_path()
    path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
    with open(path.with_suffix(".lock"), "w") as lock:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            log.info("a client daemon already serves %s", path)
            return 1
        with contextlib.suppress(FileNotFoundError):
            path.unlink()  # left by a daemon that was killed: the lock says none runs
        prepare(local_only=False)
        require_ros()
        context = Context()
        rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
        # A node keeps the context's participant, and so its view of the graph, between commands.
        watcher = rclpy.create_node(f"sm_bt_client_daemon_{os.getpid()}", context=context,
                                    start_parameter_services=False)
        server = _Server(path, context, idle)
        threading.Thread(target=_exit_when_idle, args=(server,), daemon=True).start()
        log.info("serving %s (pid %d); exits after %g s without a command", path, os.getpid(), idle)
        if ready is not None:
            ready(path)
        try:
            server.serve_forever(poll_interval=0.2)
        finally:
            server.server_close()
            server.close_pool()
            with contextlib.suppress(FileNotFoundError):
                path.unlink()
            watcher.destroy_node()
            context.try_shutdown()
    log.info("stopped")
    return 0


def _exit_when_idle(server: _Server) -> None:
    while server.idle_for() < server.idle:
        time.sleep(min(1.0, server.idle))
    log.info("no command for %g s: exiting", server.idle)
    server.shutdown()
