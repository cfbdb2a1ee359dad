"""The client daemon (``sm-bt daemon``): ``sm-bt mode``/``state`` calls run in it, with the same
answers, errors and exit codes as in a process of their own; it starts itself, steps aside for
other code, survives a killed predecessor, and exits when idle.

Each test gives the daemon a socket directory of its own (``XDG_RUNTIME_DIR``) and stops every
daemon it caused by pid (SIGINT, then SIGKILL).
"""

from __future__ import annotations

import json
import os
import re
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from ros_processes import ManagerProcess, Starter, line_within, wait_until

from sm_bt.cli import main
from sm_bt.ros import client_daemon

pytestmark = pytest.mark.ros


@pytest.fixture(name="daemons")
def daemons_fixture(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[list[int]]:
    """The daemon on: its socket under ``tmp_path``; the pids listed are stopped at teardown."""
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
    monkeypatch.setenv(client_daemon.DISABLE_VARIABLE, "1")
    pids: list[int] = []
    yield pids
    for pid in pids:
        stop_pid(pid)


def stop_pid(pid: int) -> None:
    for sig, wait in ((signal.SIGINT, 3.0), (signal.SIGKILL, 3.0)):
        try:
            os.kill(pid, sig)
        except ProcessLookupError:
            return
        give_up = time.monotonic() + wait
        while time.monotonic() < give_up:
            if not alive(pid):
                return
            time.sleep(0.05)


def alive(pid: int) -> bool:
    try:
        finished, _ = os.waitpid(pid, os.WNOHANG)  # our child: reap it
        if finished:
            return False
    except ChildProcessError:
        pass  # not our child (started by a command): it is reaped elsewhere
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return Path(f"/proc/{pid}/stat").read_text().split()[2] != "Z"


def run_daemon(pids: list[int], *args: str) -> subprocess.Popen[str]:
    """``sm-bt daemon run ARGS``, once it said READY."""
    process = subprocess.Popen([sys.executable, "-m", "sm_bt.cli", "daemon", "run", *args], text=True,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    pids.append(process.pid)
    # Fast DDS writes its own errors to stdout (seen: a shared-memory port's lock taken, under load),
    # so READY may come after such lines, as NodesProcess reads it.
    deadline = time.monotonic() + 30.0
    before: list[str] = []
    while not (line := line_within(process.stdout, max(0.1, deadline - time.monotonic()),
                                   "sm-bt daemon run: READY")).startswith("READY "):
        before.append(line)
        assert line and time.monotonic() < deadline, (before, process.stderr.read() if process.poll() is not None
                                                      and process.stderr else "")
    return process


def sm_bt(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def served(capsys: pytest.CaptureFixture[str]) -> int:
    code, out, _ = sm_bt(capsys, "daemon", "status")
    assert code == 0, out
    found = re.search(r"(\d+) commands served", out)
    assert found, out
    return int(found.group(1))


@pytest.mark.long
def test_commands_run_in_the_daemon_with_the_same_answers_and_exit_codes(
        daemons: list[int], start_manager: Callable[..., ManagerProcess], node_processes: Starter,
        capsys: pytest.CaptureFixture[str]) -> None:
    manager = start_manager("--grace-period", "0.3")
    node_processes("pilot")
    manager.ready()
    daemon = run_daemon(daemons, "--idle", "120")
    wait_until(lambda: sm_bt(capsys, "state", "get", "pilot")[1] == "pilot: unconfigured\n", 15.0,
               "the pilot never reported unconfigured through the daemon")
    before = served(capsys)

    code, out, err = sm_bt(capsys, "state", "set", "pilot", "configure", "--wait")
    assert (code, err) == (0, "") and re.fullmatch(r"pilot: inactive \d+\.\d\d s after the request\n", out), out
    code, out, err = sm_bt(capsys, "mode", "set", "pilot", "f_normal_mode", "--wait")
    assert (code, err) == (0, "") and re.fullmatch(r"pilot: f_normal_mode confirmed \d+\.\d\d s after the request\n",
                                                   out), out
    # The client's errors cross the socket as themselves: a usage error is exit 2 with the closest name.
    assert sm_bt(capsys, "mode", "set", "pilot", "f_nrmal_mode") == (
        2, "", "sm-bt mode: error: pilot has no mode 'f_nrmal_mode' (did you mean 'f_normal_mode'?)\n")
    code, _, err = sm_bt(capsys, "state", "set", "amcl", "deactivate")
    assert code == 1 and err.startswith("sm-bt: error: amcl is a node that a mode manager manages"), err
    assert sm_bt(capsys, "mode", "get", "pilot") == (0, "pilot: f_normal_mode\n", "")
    # Calls with keyword arguments cross too (a dry run; a request with a priority).
    code, out, _ = sm_bt(capsys, "mode", "set", "pilot", "f_degraded_mode", "--dry-run")
    assert code == 0 and out.startswith("change_mode pilot f_degraded_mode: "), out
    assert sm_bt(capsys, "mode", "set", "pilot", "f_slow_mode", "--priority", "60") == (
        0, "pilot: change to f_slow_mode accepted\n", "")
    assert served(capsys) == before + 7  # each command once, none in a process of its own

    assert sm_bt(capsys, "daemon", "stop")[0] == 0
    assert daemon.wait(timeout=5.0) == 0
    assert not client_daemon.socket_path().exists()


def test_a_command_starts_the_daemon_when_none_runs_and_the_next_one_uses_it(
        daemons: list[int], capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(client_daemon.DISABLE_VARIABLE, "0")
    code, _, err = sm_bt(capsys, "mode", "get", "pilot", "--timeout", "0.5")
    assert code == 1 and "nothing answers /pilot/get_mode within 0.5 s" in err, err
    assert sm_bt(capsys, "daemon", "status")[0] == 1  # SM_BT_DAEMON=0: none was started

    monkeypatch.setenv(client_daemon.DISABLE_VARIABLE, "1")
    code, _, err = sm_bt(capsys, "mode", "get", "pilot", "--timeout", "0.5")
    assert code == 1 and "nothing answers /pilot/get_mode within 0.5 s" in err, err
    wait_until(lambda: sm_bt(capsys, "daemon", "status")[0] == 0, 10.0, "no daemon started")
    daemons.append(client_daemon.ask("status")["pid"])
    assert served(capsys) == 0
    code, _, err = sm_bt(capsys, "mode", "get", "pilot", "--timeout", "0.5")
    assert code == 1 and "nothing answers /pilot/get_mode within 0.5 s" in err, err
    assert served(capsys) == 1


def test_a_daemon_of_other_code_refuses_and_exits(daemons: list[int]) -> None:
    daemon = run_daemon(daemons)
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as connection:
        connection.settimeout(5.0)
        connection.connect(str(client_daemon.socket_path()))
        connection.sendall(b'{"fingerprint": "older", "do": "client"}\n')
        answer = json.loads(connection.makefile().readline())
    assert "refused" in answer
    assert daemon.wait(timeout=5.0) == 0
    assert daemon.stderr is not None and "other sm_bt code" in daemon.stderr.read()


def test_a_killed_daemon_is_replaced_and_a_second_one_steps_aside(daemons: list[int]) -> None:
    first = run_daemon(daemons)
    first.kill()
    first.wait(timeout=5.0)
    assert client_daemon.socket_path().exists()  # left behind
    with pytest.raises(client_daemon.DaemonUnavailable):
        client_daemon.ask("status")
    second = run_daemon(daemons)
    assert client_daemon.ask("status")["pid"] == second.pid
    third = subprocess.run([sys.executable, "-m", "sm_bt.cli", "daemon", "run"], capture_output=True, text=True,
                           timeout=30.0)
    assert third.returncode == 1 and "already serves" in third.stderr, third.stderr
    assert client_daemon.ask("status")["pid"] == second.pid


def test_an_idle_daemon_exits_by_itself(daemons: list[int]) -> None:
    daemon = run_daemon(daemons, "--idle", "0.5")
    assert daemon.wait(timeout=10.0) == 0
    assert daemon.stderr is not None and "no command for 0.5 s: exiting" in daemon.stderr.read()
    assert not client_daemon.socket_path().exists()
