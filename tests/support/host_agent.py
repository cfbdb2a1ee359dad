"""A helper the across-hosts tests (tests/support/hosts.py) run inside a network namespace: it watches
a topic, or pings.

``python tests/support/host_agent.py watch TOPIC TYPE [--durability transient_local|volatile] [--depth 100]``
    subscribes to ``TOPIC`` (``TYPE`` as ``pkg/msg/Name``, reliable) and prints, one line each:
    ``READY`` once subscribed; ``PUBLISHERS N`` whenever the number of publishers it sees changes;
    ``MSG <time.monotonic()> <the message as JSON>`` per message. CLOCK_MONOTONIC is the machine's, so
    the times compare with the test's own ``time.monotonic()`` (a namespace has no clock of its own).
    The ROS environment (domain, discovery range, Fast DDS profile) is the one it is started with.

``python tests/support/host_agent.py ping ADDRESS [--count 20] [--interval 0.1] [--wait 2]``
    ICMP echo over a raw socket (root; the machine has no ``ping``): ``REPLY <seq> <rtt seconds>`` per
    answer, then ``SUMMARY sent=N received=M loss=F min=S avg=S max=S`` (times ``nan`` with no answer).

Both stop on SIGINT or SIGTERM within 2 s (exit 0), and with ``--stop-on-eof`` when stdin ends (the
harness that started it has gone). Every ROS wait has a timeout: the executor spins in steps of 0.1 s.
"""

from __future__ import annotations

import argparse
import importlib
import json
import math
import os
import select
import signal
import socket
import struct
import sys
import threading
import time
from collections.abc import Callable
from types import FrameType
from typing import Any

SPIN_STEP = 0.1
GRAPH_POLL = 0.1


def _say(line: str) -> None:
    sys.stdout.write(line + "\n")
    sys.stdout.flush()


# -- stopping -------------------------------------------------------------------------------------------

_stop = threading.Event()


def _on_signal(signum: int, frame: FrameType | None) -> None:
    _stop.set()


def _watch_stdin() -> None:
    """Stop once stdin ends (read in a daemon thread)."""
    try:
        while os.read(sys.stdin.fileno(), 4096):
            pass
    except OSError:
        pass
    _stop.set()


# -- messages as plain data -------------------------------------------------------------------------------


def message_type(name: str) -> Any:
    """The message class of ``pkg/msg/Name`` (or ``pkg/Name``)."""
    try:  # ROS's own way, where rosidl_runtime_py is installed (it is not on PyPI)
        return importlib.import_module("rosidl_runtime_py.utilities").get_message(name)
    except ImportError:
        pass
    parts = name.split("/")
    if len(parts) == 2:
        parts = [parts[0], "msg", parts[1]]
    if len(parts) != 3 or not all(parts):
        raise ValueError(f"{name!r} is not a message type (pkg/msg/Name)")
    return getattr(importlib.import_module(f"{parts[0]}.{parts[1]}"), parts[2])


def to_data(value: Any) -> Any:
    """A message (or a field of one) as dicts, lists and plain values, for JSON."""
    if hasattr(value, "get_fields_and_field_types"):
        return {field: to_data(getattr(value, field)) for field in value.get_fields_and_field_types()}
    if isinstance(value, (bytes, bytearray)):
        return list(value)
    if isinstance(value, (list, tuple)) or type(value).__name__ in ("array", "ndarray"):
        return [to_data(item) for item in value]
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    return value


def _converter() -> Callable[[Any], Any]:
    try:
        convert: Callable[[Any], Any] = importlib.import_module("rosidl_runtime_py").message_to_ordereddict
        return convert
    except ImportError:
        return to_data


# -- watch ------------------------------------------------------------------------------------------------


def watch(topic: str, type_name: str, durability: str, depth: int) -> int:
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from rclpy.signals import SignalHandlerOptions

    kind = message_type(type_name)
    convert = _converter()
    context = Context()
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node(f"sm_bt_host_agent_{os.getpid()}", context=context, start_parameter_services=False)
    qos = QoSProfile(depth=depth, reliability=ReliabilityPolicy.RELIABLE,
                     durability=(DurabilityPolicy.TRANSIENT_LOCAL if durability == "transient_local"
                                 else DurabilityPolicy.VOLATILE))

    def received(message: Any) -> None:
        now = time.monotonic()
        _say(f"MSG {now:.6f} {json.dumps(convert(message), default=str)}")

    node.create_subscription(kind, topic, received, qos)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    _say("READY")
    publishers = -1
    next_graph = 0.0
    try:
        while not _stop.is_set():
            executor.spin_once(timeout_sec=SPIN_STEP)
            now = time.monotonic()
            if now >= next_graph:
                next_graph = now + GRAPH_POLL
                count = node.count_publishers(topic)
                if count != publishers:
                    publishers = count
                    _say(f"PUBLISHERS {count}")
    except ExternalShutdownException:
        pass
    finally:
        executor.shutdown(timeout_sec=1.0)
        node.destroy_node()
        context.try_shutdown()
    return 0


# -- ping -------------------------------------------------------------------------------------------------


def _checksum(data: bytes) -> int:
    if len(data) % 2:
        data += b"\0"
    total: int = sum(struct.unpack(f"!{len(data) // 2}H", data))
    total = (total >> 16) + (total & 0xFFFF)
    total += total >> 16
    return ~total & 0xFFFF


def _echo_request(ident: int, sequence: int) -> bytes:
    payload = struct.pack("!d", time.monotonic()) + bytes(48)
    header = struct.pack("!BBHHH", 8, 0, 0, ident, sequence)
    return struct.pack("!BBHHH", 8, 0, _checksum(header + payload), ident, sequence) + payload


def ping(address: str, count: int, interval: float, wait: float) -> int:
    sock = socket.socket(socket.AF_INET, socket.SOCK_RAW, socket.IPPROTO_ICMP)
    ident = os.getpid() & 0xFFFF
    sent: dict[int, float] = {}
    rtts: dict[int, float] = {}
    next_send = time.monotonic()
    deadline = math.inf
    try:
        while not _stop.is_set():
            now = time.monotonic()
            if len(sent) < count and now >= next_send:
                sequence = len(sent) + 1
                sent[sequence] = now
                try:
                    sock.sendto(_echo_request(ident, sequence), (address, 0))
                except OSError as error:  # no route while the link is down: counted as lost
                    _say(f"ERROR {sequence} {error.strerror}")
                next_send = now + interval
                if len(sent) == count:
                    deadline = now + wait
            if now >= deadline or len(rtts) == count:
                break
            timeout = min(deadline, next_send if len(sent) < count else deadline) - now
            readable, _, _ = select.select([sock], [], [], max(0.0, min(timeout, SPIN_STEP)))
            if not readable:
                continue
            packet, _ = sock.recvfrom(65535)
            arrived = time.monotonic()
            header_length = (packet[0] & 0x0F) * 4
            icmp_type, _, _, reply_ident, sequence = struct.unpack("!BBHHH", packet[header_length:header_length + 8])
            if icmp_type == 0 and reply_ident == ident and sequence in sent and sequence not in rtts:
                rtts[sequence] = arrived - sent[sequence]
                _say(f"REPLY {sequence} {rtts[sequence]:.6f}")
    finally:
        sock.close()
    times = list(rtts.values())
    loss = 1.0 - len(times) / len(sent) if sent else math.nan
    summary = (min(times), sum(times) / len(times), max(times)) if times else (math.nan,) * 3
    _say(f"SUMMARY sent={len(sent)} received={len(times)} loss={loss:.4f} "
         f"min={summary[0]:.6f} avg={summary[1]:.6f} max={summary[2]:.6f}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="host_agent.py", description=__doc__.splitlines()[0])
    parser.add_argument("--stop-on-eof", action="store_true", help="stop when stdin ends")
    commands = parser.add_subparsers(dest="command", required=True)
    watched = commands.add_parser("watch", help="print the messages on a topic")
    watched.add_argument("topic")
    watched.add_argument("type", metavar="TYPE", help="pkg/msg/Name")
    watched.add_argument("--durability", choices=("transient_local", "volatile"), default="volatile")
    watched.add_argument("--depth", type=int, default=100)
    pinged = commands.add_parser("ping", help="ICMP echo to an address")
    pinged.add_argument("address")
    pinged.add_argument("--count", type=int, default=20)
    pinged.add_argument("--interval", type=float, default=0.1)
    pinged.add_argument("--wait", type=float, default=2.0, help="for replies after the last request")
    args = parser.parse_args(argv)
    signal.signal(signal.SIGINT, _on_signal)
    signal.signal(signal.SIGTERM, _on_signal)
    if args.stop_on_eof:
        threading.Thread(target=_watch_stdin, name="stdin", daemon=True).start()
    if args.command == "watch":
        return watch(args.topic, args.type, args.durability, args.depth)
    return ping(args.address, args.count, args.interval, args.wait)


if __name__ == "__main__":
    sys.exit(main())
