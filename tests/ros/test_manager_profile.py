"""The Fast DDS profiles of a manager's process. ``sm-bt manager`` announces its participant every
second instead of every 3 s, so that a process that joins later finds its services at once (the CLI took
0.8-3.7 s from a fresh process); asked for (``--receive-room``), it also gets room for a large
change's burst of answers; unless the user's settings configure Fast DDS. The profile is that
process's only.

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

from sm_bt.ros.environment import (
    MANAGER_PROFILE,
    RECEIVE_ROOM_PROFILE,
    TRANSPORT_SETTINGS,
    manager_profile,
    manager_profile_applies,
)

VARIABLE = "FASTRTPS_DEFAULT_PROFILES_FILE"
#: Fast DDS 2.14's port file holds its queue: 52,400 bytes for 512 samples, 206,000 for 8,192.
ROOMY_PORT_BYTES = 150_000
#: Both profiles' announcement period (Fast DDS's default: 3 s).
ANNOUNCED = "<leaseAnnouncement>\n            <sec>1</sec>\n            <nanosec>0</nanosec>"


@pytest.fixture
def clean(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> pytest.MonkeyPatch:
    for name in (*TRANSPORT_SETTINGS, "RMW_IMPLEMENTATION"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.chdir(tmp_path)
    return monkeypatch


@pytest.mark.parametrize(("room", "expected"), [(False, MANAGER_PROFILE), (True, RECEIVE_ROOM_PROFILE)])
def test_with_nothing_of_the_users_the_profile_is_set_while_the_participant_is_made(
        clean: pytest.MonkeyPatch, room: bool, expected: str) -> None:
    with manager_profile(room=room) as profile:
        assert profile == expected and os.environ[VARIABLE] == expected
        text = Path(expected).read_text()
        assert ANNOUNCED in text
        assert ("<port_queue_capacity>8192</port_queue_capacity>" in text) == room
        assert ("<userTransports>" in text) == room  # without the room, Fast DDS's transports untouched
    assert VARIABLE not in os.environ  # processes the manager starts later keep Fast DDS's defaults


@pytest.mark.parametrize("room", [False, True])
@pytest.mark.parametrize(("name", "value"), [
    ("FASTRTPS_DEFAULT_PROFILES_FILE", "/etc/robot/dds.xml"),
    ("FASTDDS_DEFAULT_PROFILES_FILE", "/etc/robot/dds.xml"),
    ("FASTDDS_BUILTIN_TRANSPORTS", "UDPv4"),
    ("RMW_IMPLEMENTATION", "rmw_cyclonedds_cpp"),
])
def test_the_users_settings_stand(clean: pytest.MonkeyPatch, name: str, value: str, room: bool) -> None:
    clean.setenv(name, value)
    with manager_profile(room=room) as profile:
        assert profile is None and os.environ.get(VARIABLE) == (value if name == VARIABLE else None)
    assert os.environ.get(name) == value


def test_a_profile_fast_dds_finds_in_the_working_directory_stands(clean: pytest.MonkeyPatch, tmp_path: Path) -> None:
    assert manager_profile_applies()
    (tmp_path / "DEFAULT_FASTRTPS_PROFILES.xml").write_text("<profiles/>")
    assert not manager_profile_applies()
    clean.setenv("RMW_IMPLEMENTATION", "rmw_fastrtps_dynamic_cpp")  # reads the same profiles
    assert not manager_profile_applies()


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
    the CLI): so it is asked for, never the default. By default the manager only announces itself
    more often, with Fast DDS's transports as they are."""
    for name in TRANSPORT_SETTINGS:
        monkeypatch.delenv(name, raising=False)
    node_processes("pilot")
    manager = start_manager().ready()
    wait_until(lambda: manager.lines("transports:"), 5.0, "no transports line")
    assert manager.lines("transports:") == [f"transports: Fast DDS with sm_bt's announcements ({MANAGER_PROFILE})"]
