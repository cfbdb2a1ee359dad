"""A manager's process asked for room for a large change's burst of answers (``--receive-room``,
sm_bt's Fast DDS profile) gets it, unless the user's settings choose the transports; the room is
that process's only, and never the default.

With Fast DDS's 512-sample shared-memory port, a 200-node change lost answers and events that then
came 3 s late (docs/ros-interface.md, "Receive room"). Seen here as a person would check it: the
port files the manager's process maps, and the line it logs.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import pytest
from ros_processes import ManagerProcess, Starter, wait_until

from sm_bt.ros.environment import RECEIVE_ROOM_PROFILE, TRANSPORT_SETTINGS, receive_room, receive_room_applies

VARIABLE = "FASTRTPS_DEFAULT_PROFILES_FILE"
#: Fast DDS 2.14's port file holds its queue: 52,400 bytes for 512 samples, 206,000 for 8,192.
ROOMY_PORT_BYTES = 150_000


@pytest.fixture
def clean(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> pytest.MonkeyPatch:
    for name in (*TRANSPORT_SETTINGS, "RMW_IMPLEMENTATION"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.chdir(tmp_path)
    return monkeypatch


def test_with_nothing_of_the_users_the_profile_is_set_while_the_participant_is_made(clean: pytest.MonkeyPatch) -> None:
    with receive_room() as roomy:
        assert roomy and os.environ[VARIABLE] == RECEIVE_ROOM_PROFILE
        assert "<port_queue_capacity>8192</port_queue_capacity>" in Path(RECEIVE_ROOM_PROFILE).read_text()
    assert VARIABLE not in os.environ  # processes the manager starts later keep Fast DDS's defaults


@pytest.mark.parametrize(("name", "value"), [
    ("FASTRTPS_DEFAULT_PROFILES_FILE", "/etc/robot/dds.xml"),
    ("FASTDDS_DEFAULT_PROFILES_FILE", "/etc/robot/dds.xml"),
    ("FASTDDS_BUILTIN_TRANSPORTS", "UDPv4"),
    ("RMW_IMPLEMENTATION", "rmw_cyclonedds_cpp"),
])
def test_the_users_settings_stand(clean: pytest.MonkeyPatch, name: str, value: str) -> None:
    clean.setenv(name, value)
    with receive_room() as roomy:
        assert not roomy and os.environ.get(VARIABLE) == (value if name == VARIABLE else None)
    assert os.environ.get(name) == value


def test_a_profile_fast_dds_finds_in_the_working_directory_stands(clean: pytest.MonkeyPatch, tmp_path: Path) -> None:
    assert receive_room_applies()
    (tmp_path / "DEFAULT_FASTRTPS_PROFILES.xml").write_text("<profiles/>")
    assert not receive_room_applies()
    clean.setenv("RMW_IMPLEMENTATION", "rmw_fastrtps_dynamic_cpp")  # reads the same profiles
    assert not receive_room_applies()


def _mapped_ports(pid: int) -> dict[str, int]:
    """The Fast DDS shared-memory port files a process maps, with their sizes."""
    ports: dict[str, int] = {}
    for line in Path(f"/proc/{pid}/maps").read_text().splitlines():
        path = line.split()[-1]
        if path.startswith("/dev/shm/fastrtps_port") and not path.endswith("_el") and os.path.exists(path):
            ports[path] = os.path.getsize(path)
    return ports


@pytest.mark.parametrize("users", [False, True], ids=["asked", "asked-but-users-settings"])
def test_sm_bt_manager_asked_for_room_listens_with_it_unless_the_user_chose(
        start_manager: Callable[..., ManagerProcess], node_processes: Starter, monkeypatch: pytest.MonkeyPatch,
        users: bool) -> None:
    for name in TRANSPORT_SETTINGS:
        monkeypatch.delenv(name, raising=False)
    if users:  # Fast DDS's own transports, named: the manager must not replace them
        monkeypatch.setenv("FASTDDS_BUILTIN_TRANSPORTS", "DEFAULT")
    node_processes("pilot")
    manager = start_manager("--receive-room").ready()
    wait_until(lambda: manager.lines("transports:"), 5.0, "no transports line")
    assert manager.process is not None
    pid = manager.process.pid
    wait_until(lambda: bool(_mapped_ports(pid)), 5.0, "the manager maps no port")
    # It maps its own ports (to listen) and others' (to send to them); a port's owner sized it, and
    # the test's stops remove the files of ports no process holds any more.
    ports = _mapped_ports(pid)
    if users:
        # Its ports keep Fast DDS's size, but the port every participant of the machine shares
        # (fastrtps_port7000, whatever the domain) may have been made by a roomy manager elsewhere.
        assert manager.lines("transports:") == ["transports: the middleware's, as this environment sets them"]
    else:
        roomy = f"transports: Fast DDS with sm_bt's receive room ({RECEIVE_ROOM_PROFILE})"
        assert manager.lines("transports:") == [roomy]
        assert max(ports.values()) >= ROOMY_PORT_BYTES, ports


def test_sm_bt_manager_has_no_room_unless_asked(
        start_manager: Callable[..., ManagerProcess], node_processes: Starter, monkeypatch: pytest.MonkeyPatch) -> None:
    """The room also sizes the port that every Fast DDS participant of the machine shares when the
    manager makes it first, and other processes then missed the manager in discovery (a monitor,
    the CLI): so it is asked for, never the default."""
    for name in TRANSPORT_SETTINGS:
        monkeypatch.delenv(name, raising=False)
    node_processes("pilot")
    manager = start_manager().ready()
    wait_until(lambda: manager.lines("transports:"), 5.0, "no transports line")
    assert manager.lines("transports:") == ["transports: the middleware's, as this environment sets them"]
