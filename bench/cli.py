"""The CLI against a running manager: a whole ``sm-bt mode get`` / ``mode set --wait`` as a shell
times it, in a fresh process each, with the client daemon running and without it.

The pilot's simulated nodes and ``sm-bt manager pilot`` run in processes of their own. Each
command is timed from outside (its wall time, start-up included) and, for ``--wait``, from inside
(the confirmation time it prints). Goal: every call ≤ 1 s once the manager is known (the daemon
running); without the daemon a fresh process must first discover the graph (0.1-3 s here).
"""

from __future__ import annotations

import os
import re
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from typing import Any

from bench.figures import Figure

#: Seconds a whole CLI call may take once the manager is known (issue 30).
CALL_GOAL = 1.0


def _command(env: dict[str, str], *argv: str) -> tuple[float, str]:
    began = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "sm_bt.cli", *argv], env=env, capture_output=True, text=True,
                          timeout=60.0, check=False)
    took = time.perf_counter() - began
    if done.returncode != 0:
        raise RuntimeError(f"sm-bt {' '.join(argv)}: exit {done.returncode}: {done.stderr.strip()}")
    return took, done.stdout


def _stop(process: subprocess.Popen[Any]) -> None:
    for sig in (signal.SIGINT, signal.SIGKILL):
        if process.poll() is not None:
            return
        process.send_signal(sig)
        try:
            process.wait(timeout=3.0)
        except subprocess.TimeoutExpired:
            continue


def _series(env: dict[str, str], turns: int) -> dict[str, list[float]]:
    """``turns`` of: mode get, then mode set to the other mode with --wait (wall and printed times)."""
    times: dict[str, list[float]] = {"get": [], "set": [], "confirmed": []}
    for turn in range(turns):
        took, _ = _command(env, "mode", "get", "pilot")
        times["get"].append(took)
        mode = ("f_degraded_mode", "f_normal_mode")[turn % 2]
        took, out = _command(env, "mode", "set", "pilot", mode, "--wait")
        times["set"].append(took)
        found = re.search(r"confirmed (\d+\.\d+) s", out)
        times["confirmed"].append(float(found.group(1)) if found else float("nan"))
    return times


def run(quick: bool) -> list[Figure]:
    from sm_bt.ros.environment import prepare, require_ros

    prepare(own_domain=True)
    require_ros()
    turns = 2 if quick else 8
    started: list[subprocess.Popen[Any]] = []
    with tempfile.TemporaryDirectory(prefix="sm_bt-bench-cli-") as tmp:
        env = {**os.environ, "XDG_RUNTIME_DIR": tmp, "SM_BT_DAEMON": "1"}
        try:
            for argv in (("sim-nodes", "pilot"), ("manager", "pilot")):
                started.append(subprocess.Popen([sys.executable, "-m", "sm_bt.cli", *argv], env=env,
                                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
            daemon = subprocess.Popen([sys.executable, "-m", "sm_bt.cli", "daemon", "run"], env=env, text=True,
                                      stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
            started.append(daemon)
            assert daemon.stdout is not None and daemon.stdout.readline().startswith("READY")
            give_up = time.monotonic() + 60.0
            while _command(env, "state", "get", "pilot")[1] != "pilot: unconfigured\n":
                if time.monotonic() > give_up:
                    raise RuntimeError("the pilot never came up")
                time.sleep(0.2)
            _command(env, "state", "set", "pilot", "configure", "--wait")
            known = _series(env, turns)
            fresh = _series({**env, "SM_BT_DAEMON": "0"}, turns)
        finally:
            for process in reversed(started):
                _stop(process)
    worst = max(known["get"] + known["set"])
    details = {"turns": turns, "known": known, "fresh": fresh}
    return [
        Figure("CLI", "slowest mode get / mode set --wait, daemon running", worst, "s", CALL_GOAL, details=details),
        Figure("CLI", "median mode get, daemon running", statistics.median(known["get"]), "s"),
        Figure("CLI", "median mode get, fresh process (no daemon)", statistics.median(fresh["get"]), "s"),
        Figure("CLI", "slowest mode get, fresh process (no daemon)", max(fresh["get"]), "s"),
        Figure("CLI", "median confirmation printed by --wait, daemon running", statistics.median(known["confirmed"]),
               "s"),
        Figure("CLI", "median confirmation printed by --wait, fresh process", statistics.median(fresh["confirmed"]),
               "s"),
    ]
