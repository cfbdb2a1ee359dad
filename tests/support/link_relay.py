"""A lossy, slow link in user space: forward Ethernet frames between two interfaces, dropping and delaying them.

The kernel here has neither ``sch_netem`` nor tc actions, so the across-hosts tests (tests/support/hosts.py) put
this relay in a namespace of its own between two veth pairs::

    python tests/support/link_relay.py IF_A IF_B --loss 0.3 --delay 0.2 [--seed N] [--control]

Every frame that arrives on one interface goes out of the other one, in each direction independently:
dropped with probability ``loss``, the others sent ``delay`` seconds after they arrived (order kept).
One thread: ``select`` over both sockets (and the control input), and a heap of frames waiting for their
time.

How frames are read and written: ``AF_PACKET`` raw sockets for every protocol (``ETH_P_ALL``), bound to
one interface each, promiscuous, with ``PACKET_VNET_HDR``. The virtio-net header that comes with each
frame carries the kernel's offload state, and sending the frame back with it keeps that state: a veth
hands over UDP and TCP packets whose checksum is only partly computed (checksum offload) and TCP frames
far larger than the MTU (segmentation offload), which, sent as plain frames, would arrive with a wrong
checksum (silently dropped by the receiver's stack) or be refused as too long. Frames this relay sent
itself show up on its own socket as outgoing (``PACKET_OUTGOING``) and are skipped.

Prints ``READY`` once it forwards. With ``--control``, reads commands from stdin, one a line, and
answers each on stdout: ``set LOSS DELAY`` (``OK``), ``stats`` (``STATS`` and counts); the end of stdin
(the harness has gone) stops it. SIGINT or SIGTERM stop it cleanly (exit 0); so does ``quit``.
"""

from __future__ import annotations

import argparse
import errno
import heapq
import os
import random
import select
import signal
import socket
import struct
import sys
import time
from types import FrameType

ETH_P_ALL = 0x0003
SOL_PACKET = 263
PACKET_ADD_MEMBERSHIP = 1
PACKET_MR_PROMISC = 1
PACKET_VNET_HDR = 15
PACKET_OUTGOING = 4
#: struct virtio_net_hdr: flags, gso_type, hdr_len, gso_size, csum_start, csum_offset.
VNET_HDR_LEN = 10
#: A frame with segmentation offload can be up to 64 KiB of payload plus headers.
BUFFER = 65536 + VNET_HDR_LEN + 256


class Stop(Exception):
    """A signal asked the relay to stop."""


def _stop(signum: int, frame: FrameType | None) -> None:
    raise Stop()


def packet_socket(interface: str) -> socket.socket:
    """A raw, non-blocking packet socket on ``interface``: every frame, promiscuous, with virtio-net headers."""
    sock = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(ETH_P_ALL))
    sock.setsockopt(SOL_PACKET, PACKET_VNET_HDR, 1)
    sock.bind((interface, ETH_P_ALL))
    index = socket.if_nametoindex(interface)
    membership = struct.pack("iHH8s", index, PACKET_MR_PROMISC, 0, b"")
    sock.setsockopt(SOL_PACKET, PACKET_ADD_MEMBERSHIP, membership)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 * 1024 * 1024)
    sock.setblocking(False)
    return sock


class Relay:
    def __init__(self, a: str, b: str, loss: float, delay: float, seed: int | None) -> None:
        self.names = (a, b)
        self.sockets = (packet_socket(a), packet_socket(b))
        self.loss = loss
        self.delay = delay
        self.random = random.Random(seed)
        #: (due time, sequence number, index of the socket to send on, frame with its virtio-net header)
        self.queue: list[tuple[float, int, int, bytes]] = []
        self.sequence = 0
        self.counts = {"received": 0, "dropped": 0, "sent": 0, "send_errors": 0}

    def close(self) -> None:
        for sock in self.sockets:
            sock.close()

    def receive(self, index: int) -> None:
        """Take every frame waiting on socket ``index``, queueing those not dropped for the other one."""
        sock = self.sockets[index]
        while True:
            try:
                frame, address = sock.recvfrom(BUFFER)
            except (BlockingIOError, InterruptedError):
                return
            except OSError as error:  # the interface went away (ENETDOWN): nothing to read now
                if error.errno in (errno.ENETDOWN, errno.ENXIO, errno.ENODEV):
                    return
                raise
            if address[2] == PACKET_OUTGOING:  # one this relay sent
                continue
            self.counts["received"] += 1
            if self.loss > 0 and self.random.random() < self.loss:
                self.counts["dropped"] += 1
                continue
            self.sequence += 1
            heapq.heappush(self.queue, (time.monotonic() + self.delay, self.sequence, 1 - index, frame))

    def send_due(self) -> float | None:
        """Send every frame whose time has come; seconds until the next one (``None``: none waits)."""
        while self.queue:
            due, _, index, frame = self.queue[0]
            now = time.monotonic()
            if due > now:
                return due - now
            heapq.heappop(self.queue)
            try:
                self.sockets[index].send(frame)
                self.counts["sent"] += 1
            except OSError:  # a link that is down, a full queue: the frame is lost, as on a wire
                self.counts["send_errors"] += 1
        return None

    def command(self, line: str) -> bool:
        """Carry out one control line; ``False`` to stop."""
        words = line.split()
        if not words:
            return True
        if words[0] == "quit":
            return False
        if words[0] == "set" and len(words) == 3:
            try:
                loss, delay = float(words[1]), float(words[2])
            except ValueError:
                loss = delay = -1.0
            if 0.0 <= loss <= 1.0 and delay >= 0.0:
                self.loss, self.delay = loss, delay
                _say(f"OK loss={loss:g} delay={delay:g}")
                return True
        if words[0] == "stats":
            _say("STATS " + " ".join(f"{key}={value}" for key, value in self.counts.items())
                 + f" queued={len(self.queue)}")
            return True
        _say(f"ERROR not understood: {line.strip()!r}")
        return True

    def run(self, control: bool) -> None:
        readers: list[int] = [sock.fileno() for sock in self.sockets]
        stdin = sys.stdin.fileno()
        if control:
            readers.append(stdin)
        pending = b""
        _say("READY")
        while True:
            wait = self.send_due()
            readable, _, _ = select.select(readers, [], [], wait)
            for fd in readable:
                if fd == stdin:
                    chunk = os.read(stdin, 4096)
                    if not chunk:  # whoever controlled the relay has gone
                        return
                    pending += chunk
                    while b"\n" in pending:
                        line, pending = pending.split(b"\n", 1)
                        if not self.command(line.decode(errors="replace")):
                            return
                else:
                    self.receive(0 if fd == readers[0] else 1)


def _say(line: str) -> None:
    sys.stdout.write(line + "\n")
    sys.stdout.flush()


def _fraction(text: str) -> float:
    value = float(text)
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"{text} is not a probability from 0 to 1")
    return value


def _seconds(text: str) -> float:
    value = float(text)
    if value < 0.0:
        raise argparse.ArgumentTypeError(f"{text} is negative")
    return value


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="link_relay.py", description=__doc__.splitlines()[0])
    parser.add_argument("a", metavar="IF_A")
    parser.add_argument("b", metavar="IF_B")
    parser.add_argument("--loss", type=_fraction, default=0.0, help="probability of dropping each frame")
    parser.add_argument("--delay", type=_seconds, default=0.0, help="seconds each frame waits")
    parser.add_argument("--seed", type=int, default=None, help="of the random drops")
    parser.add_argument("--control", action="store_true",
                        help="read commands on stdin (set LOSS DELAY, stats, quit); stop at its end")
    args = parser.parse_args(argv)
    signal.signal(signal.SIGINT, _stop)
    signal.signal(signal.SIGTERM, _stop)
    relay: Relay | None = None
    try:
        relay = Relay(args.a, args.b, args.loss, args.delay, args.seed)
        relay.run(args.control)
    except Stop:
        pass
    finally:
        if relay is not None:
            relay.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
