"""``sm-bt mission MODEL TREE``: host a mission tree on ROS 2 (one node, the manager embedded).

From a shell or a launch file; the model and tree may also come as ROS parameters, as launch
files usually pass them::

    sm-bt mission robot.yaml mission.xml --rate 10
    sm-bt mission --ros-args -p model:=robot.yaml -p tree:=mission.xml -r __node:=mission

``TREE`` is a tree file (``.xml``, checked against the model) or ``package.module:function``
returning the root. The node (``sm_bt_mission`` unless remapped) serves the system_modes interface
of the model's parts and the tree's snapshot streams (:class:`~sm_bt.ros.host.MissionHost`). The
tree runs until its root succeeds (exit 0) or fails (1), or the process gets SIGINT/SIGTERM (0).
Discovery and the domain are the user's, so nodes may be on other machines. It logs one line per
change of the root's status and per mode or state a system reaches, to stderr.
"""

from __future__ import annotations

import argparse
import logging
import signal
from typing import Any

from sm_bt.cli.arguments import non_negative, positive
from sm_bt.cli.common import CliError, load, shipped_nodes
from sm_bt.model.errors import ModelError

log = logging.getLogger("sm_bt.ros.host")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", nargs="?", metavar="MODEL",
                        help="model file, or a bundled model's name (or the ROS parameter model)")
    parser.add_argument("tree", nargs="?", metavar="TREE",
                        help="a .xml tree file or package.module:function (or the ROS parameter tree)")
    parser.add_argument("--rate", type=positive, default=None, metavar="HZ",
                        help="ticks per second (default 10, or the ROS parameter rate)")
    parser.add_argument("--wait-for-nodes", type=non_negative, default=None, metavar="SECONDS",
                        help="wait this long for the model's nodes before the first tick (default 10; 0: do not "
                             "wait; or the ROS parameter wait_for_nodes)")
    parser.add_argument("--ros-args", nargs=argparse.REMAINDER, default=[], dest="ros_args", metavar="ARG",
                        help="the rest goes to ROS 2 (parameters -p, remapping -r __node:=NAME, ...)")


def _settings(node: Any, args: argparse.Namespace) -> tuple[str, str, float, float]:
    """The command line's values, else the node's ROS parameters (declared either way, so that
    ``ros2 param get`` shows what the mission runs with)."""
    from sm_bt.ros.host import declare

    def setting(name: str, given: Any, default: Any, description: str) -> Any:
        value = declare(node, name, default, description)
        return value if given is None else given

    model = setting("model", args.model, "", "SMH model file, or a bundled model's name")
    tree = setting("tree", args.tree, "", "mission tree: a .xml file or package.module:function")
    rate = setting("rate", args.rate, 10.0, "ticks per second")
    wait = setting("wait_for_nodes", args.wait_for_nodes, 10.0, "seconds to wait for the model's nodes (0: do not)")
    if not model or not tree:
        missing = " and ".join(name for name, value in (("model", model), ("tree", tree)) if not value)
        raise CliError(f"give the {missing}: sm-bt mission MODEL TREE, or as ROS parameters "
                       "(--ros-args -p model:=robot.yaml -p tree:=mission.xml)")
    return str(model), str(tree), float(rate), float(wait)


def run(args: argparse.Namespace) -> int:
    from sm_bt.ros.console_log import configure_logging
    from sm_bt.ros.environment import RosUnavailable, prepare, require_ros

    configure_logging("info")
    prepare(local_only=False)  # a robot's nodes may be on other machines: the user's discovery
    try:
        require_ros()
    except RosUnavailable as error:
        raise CliError(str(error)) from None
    from py_trees.common import Status

    from sm_bt.ros.host import HostError, MissionHost, load_root, mission_node

    with mission_node(args.ros_args) as node:
        host: MissionHost | None = None
        try:
            model_name, tree_spec, rate, wait = _settings(node, args)
            try:
                model = load(model_name)
            except ModelError as error:
                raise CliError(f"the model has mistakes:\n{error}") from None
            shipped_nodes()
            host = MissionHost(model, load_root(tree_spec, model), node, rate=rate)
            _stop_on_signals(host.stop)
            log.info("mission %s on node %s: %s at %g Hz, model %s", tree_spec, node.get_fully_qualified_name(),
                     host.tree.root.name, rate, model.path)
            if wait > 0:
                host.wait_for_nodes(wait)
            return 1 if host.run() is Status.FAILURE else 0
        except HostError as error:
            raise CliError(str(error)) from None
        finally:
            if host is not None:
                host.close()


def _stop_on_signals(stop: Any) -> None:
    def handler(signum: int, frame: object) -> None:
        stop()

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)


