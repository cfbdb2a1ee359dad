"""The process environment ROS 2 needs, set before rclpy starts, and a clear error without it.

DDS reads its settings when the first participant starts, so :func:`prepare` must run before
``rclpy.init``. Discovery stays on this machine unless the user chose otherwise; the domain id
is the user's, or, for self-contained runs (demo, tests), one chosen for this run so that
parallel runs on one machine do not see each other's nodes.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from importlib.resources import files

from sm_bt.model.errors import Error

#: What to install when rclpy or the interface package is missing.
INSTALL_HINT = ("install the ROS 2 extra: `pip install -c constraints.txt -e '.[ros]'` then "
                "`tools/ensure_interfaces.sh`, or simply `make test` / `make demo` from the repository")


class RosUnavailable(Error, RuntimeError):
    """rclpy or an interface package (system_modes_msgs, sm_bt_msgs) cannot be imported in this
    environment, or the ROS 2 settings in it are not valid (see :func:`check_settings`)."""


#: rcl accepts these domain ids (the DDS port mapping leaves room for no more).
MAX_DOMAIN_ID = 232
#: The values of ROS_AUTOMATIC_DISCOVERY_RANGE that rcl knows.
DISCOVERY_RANGES = ("SUBNET", "LOCALHOST", "OFF", "SYSTEM_DEFAULT")


def check_settings() -> None:
    """Raise :class:`RosUnavailable` naming the variable and the fix when ``ROS_DOMAIN_ID`` or
    ``ROS_AUTOMATIC_DISCOVERY_RANGE`` holds what rcl would refuse (rcl's own error says
    "failed to initialize rcl")."""
    domain = os.environ.get("ROS_DOMAIN_ID", "")
    if domain.strip() and not (domain.strip().isdigit() and int(domain) <= MAX_DOMAIN_ID):
        raise RosUnavailable(f"ROS_DOMAIN_ID={domain!r} is not a ROS 2 domain id: set it to a whole number from 0 to "
                             f"{MAX_DOMAIN_ID} (robots that should see each other use the same one), or unset it "
                             "for the default, 0")
    reach = os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "")
    if reach and reach not in DISCOVERY_RANGES:
        raise RosUnavailable(f"ROS_AUTOMATIC_DISCOVERY_RANGE={reach!r} is not a discovery range: use one of "
                             f"{', '.join(DISCOVERY_RANGES)}, or unset it")


def run_domain_id() -> int:
    """A domain id for a self-contained run: 10..99, from the process id."""
    return 10 + os.getpid() % 90


def prepare(*, own_domain: bool = False, local_only: bool = True) -> None:
    """Set what DDS reads at start-up, keeping whatever the user already set.

    ``own_domain`` picks a per-run ``ROS_DOMAIN_ID`` when none is set (demo, tests); otherwise
    ROS's default domain applies. ``local_only`` keeps discovery on this machine unless the user
    chose a range; ``False`` leaves ROS's default (a robot spread over machines).
    """
    if local_only:
        os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    if own_domain:
        os.environ.setdefault("ROS_DOMAIN_ID", str(run_domain_id()))
    if "ROS_LOG_DIR" not in os.environ:
        os.environ["ROS_LOG_DIR"] = os.path.join(tempfile.gettempdir(), f"sm_bt-roslog-{os.getuid()}")
    check_settings()


def describe_discovery() -> str:
    """The discovery settings in effect, in a line: what decides who sees whom."""
    domain = os.environ.get("ROS_DOMAIN_ID", "").strip() or "0 (unset)"
    reach = os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "") or "SUBNET (unset: ROS's default)"
    peers = os.environ.get("ROS_STATIC_PEERS", "").strip()
    return (f"ROS_DOMAIN_ID={domain}, ROS_AUTOMATIC_DISCOVERY_RANGE={reach}"
            + (f", ROS_STATIC_PEERS={peers}" if peers else ""))


def require_ros() -> None:
    """Raise :class:`RosUnavailable` with the fix when rclpy or an interface package
    (system_modes_msgs, sm_bt_msgs) is missing."""
    try:
        import rclpy  # noqa: F401
        from sm_bt_msgs.srv import PreviewChange  # noqa: F401
        from system_modes_msgs.srv import ChangeMode  # noqa: F401
    except ImportError as error:
        raise RosUnavailable(f"ROS 2 is not available here ({error}): {INSTALL_HINT}") from None


#: sm_bt's Fast DDS profile for a manager's process: it announces itself every second instead of every 3 s,
#: so that a process that joins later finds its services at once (docs/ros-interface.md, "The
#: manager's profile").
MANAGER_PROFILE = str(files("sm_bt.ros") / "manager.xml")
#: The same with a shared-memory port queue of 8192 samples instead of 512 ("Receive room").
RECEIVE_ROOM_PROFILE = str(files("sm_bt.ros") / "receive_room.xml")
#: What decides a process's Fast DDS transports when set: then the user's settings stand.
TRANSPORT_SETTINGS = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE",
                      "FASTDDS_BUILTIN_TRANSPORTS")
#: The profile Fast DDS loads from the working directory when no variable names one.
LOCAL_PROFILE = "DEFAULT_FASTRTPS_PROFILES.xml"
#: The middlewares that read Fast DDS profiles (Jazzy's default is the first).
FAST_DDS = ("rmw_fastrtps_cpp", "rmw_fastrtps_dynamic_cpp")


def manager_profile_applies() -> bool:
    """Whether sm_bt's profiles may be used here: the middleware is Fast DDS and nothing of the
    user's (:data:`TRANSPORT_SETTINGS`, :data:`LOCAL_PROFILE`) configures it."""
    return (os.environ.get("RMW_IMPLEMENTATION", "") or FAST_DDS[0]) in FAST_DDS \
        and not any(os.environ.get(name) for name in TRANSPORT_SETTINGS) and not os.path.exists(LOCAL_PROFILE)


@contextmanager
def manager_profile(*, room: bool = False) -> Iterator[str | None]:
    """For the process that holds a manager, around its first ROS participant (``RosRuntime``'s
    making): :data:`MANAGER_PROFILE`, or with ``room`` :data:`RECEIVE_ROOM_PROFILE`, when
    :func:`manager_profile_applies`; yields the profile used, or None.

    Fast DDS reads a profile once per process and applies it to every participant the process
    makes, so only an executable whose process is the manager's may use this (``sm-bt manager``),
    never a library call. The variable is unset again afterwards: processes started later keep
    Fast DDS's defaults."""
    if not manager_profile_applies():
        yield None
        return
    profile = RECEIVE_ROOM_PROFILE if room else MANAGER_PROFILE
    os.environ["FASTRTPS_DEFAULT_PROFILES_FILE"] = profile
    try:
        yield profile
    finally:
        os.environ.pop("FASTRTPS_DEFAULT_PROFILES_FILE", None)
