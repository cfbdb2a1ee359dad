"""A fleet on one machine: N robot "hosts" and a brain, each in a network namespace of its own, on one switch.

:class:`FleetHosts` is tests/support/hosts.py's :class:`~hosts.Hosts` with a star instead of a relay::

    robot1 ns  veth-fleet 10.198.X.1/24   <->  port-robot1 ┐
    ...                                                     ├ br-fleet  (switch ns: a Linux bridge, no addresses)
    robotN ns  veth-fleet 10.198.X.N/24   <->  port-robotN ┤
    brain ns   veth-fleet 10.198.X.254/24 <->  port-brain  ┘

The bridge forwards every frame in the kernel, at once; its multicast snooping is off (with no IGMP querier
a port that comes back would otherwise stay out of the DDS multicast groups), and so is STP (a port
forwards as soon as it is up). :meth:`FleetHosts.cut` pulls one host's cable: its switch port goes down,
so the host's veth loses its carrier (by choice, the host's own veth goes down instead);
:meth:`FleetHosts.heal` plugs it back and routes multicast again. A host is ``robot1`` ... ``robotN`` or
``brain``, the names :meth:`FleetHosts.nodes`, :meth:`FleetHosts.manager`, :meth:`FleetHosts.helper` (a
line-driven child such as tests/support/fleet_agent.py), :meth:`~hosts.Hosts.watch`, :meth:`~hosts.Hosts.sm_bt`
and :meth:`~hosts.Hosts.command` take as ``side``; :meth:`FleetHosts.robots_up` starts every robot (its
nodes and its own manager, ``--namespace /robotK``) at once.

Everything else is the two hosts' (imported, not copied): every process gets ``ROS_AUTOMATIC_DISCOVERY_RANGE=
SUBNET``, the run's ``ROS_DOMAIN_ID``, its log dir and the UDPv4-only Fast DDS profile (the namespaces share
``/dev/shm``: the shared-memory transport would bypass the switch); each namespace routes 224.0.0.0/4 over
its veth (discovery is plain multicast); processes are started as ``ip netns exec NS env ... python`` (the
PID held is python's) and :meth:`FleetHosts.close` stops them by PID (SIGINT, SIGKILL 10 s later: twenty
processes leave at once), deletes every namespace (their veths and the bridge with them) and the temp dir,
and never signals a process it did not start. Names carry the test process's PID and a counter: parallel
runs do not meet. Needs root.
"""

from __future__ import annotations

import contextlib
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from hosts import (
    _ROUND_TRIP,
    Helper,
    HostNodeProcess,
    Hosts,
    Ping,
    _what,
    ip,
    require_root,
    stop_processes,
)
from ros_processes import ManagerProcess, NodeProcess

from sm_bt.ros.node_process import READY_TIMEOUT

BRAIN = "brain"
SWITCH = "switch"
BRIDGE = "br-fleet"
VETH = "veth-fleet"
#: Seconds a heal waits for a datagram to cross to a host it plugged back.
HEAL_PROBE_TIMEOUT = 10.0
#: ``close()`` sends SIGINT to every process, then SIGKILL this long after (hosts.py: 3 s): twenty ROS
#: processes leaving at once on two cores take longer than one.
CLOSE_GRACE = 10.0


class FleetHosts(Hosts):
    """``robots`` robot hosts, the brain and the switch between them; see the module's doc.

    ``open()`` makes them, ``close()`` removes everything (idempotent); also a context manager."""

    def __init__(self, robots: int, *, domain_id: int | None = None) -> None:
        if robots < 1 or robots > 250:
            raise ValueError(f"robots={robots}: 1 to 250")
        super().__init__(domain_id=domain_id)
        self.robots = [f"robot{k}" for k in range(1, robots + 1)]
        #: Every host: the robots, then the brain.
        self.hosts = [*self.robots, BRAIN]
        self.namespaces = {host: f"smbt-{host}-{self.tag}" for host in self.hosts}
        self.namespaces[SWITCH] = f"smbt-switch-{self.tag}"
        self.veths = {host: VETH for host in self.hosts}
        #: Each host's port on the switch (the other end of its veth, in the switch's namespace).
        self.ports = {host: f"port-{host}" for host in self.hosts}
        subnet = f"10.198.{1 + int(self.tag.split('-')[0]) % 250}"
        self.addresses = {robot: f"{subnet}.{k}" for k, robot in enumerate(self.robots, 1)}
        self.addresses[BRAIN] = f"{subnet}.254"
        self.directory = Path(tempfile.gettempdir()) / f"smbt-fleet-hosts-{self.tag}"

    def __enter__(self) -> FleetHosts:
        self.open()
        return self

    def _make(self) -> None:
        self._make_namespaces("smbt-fleet-hosts")
        switch = self.namespaces[SWITCH]
        ip("-n", switch, "link", "add", BRIDGE, "type", "bridge", "stp_state", "0", "mcast_snooping", "0")
        ip("-n", switch, "link", "set", BRIDGE, "up")
        for host in self.hosts:
            namespace = self.namespaces[host]
            # Both ends made in their namespaces at once: no veth ever appears in the machine's namespace.
            ip("link", "add", VETH, "netns", namespace, "type", "veth", "peer", "name", self.ports[host],
               "netns", switch)
            ip("-n", switch, "link", "set", self.ports[host], "master", BRIDGE)
            ip("-n", switch, "link", "set", self.ports[host], "up")
            ip("-n", namespace, "addr", "add", f"{self.addresses[host]}/24", "dev", VETH)
            ip("-n", namespace, "link", "set", VETH, "up")
            self._route_multicast(host)

    def close(self) -> None:
        """:meth:`hosts.Hosts.close`, its processes given :data:`CLOSE_GRACE` s after SIGINT."""
        if self._closed:
            return
        started = time.monotonic()
        for manager in self._managers:
            manager.join_starter()
        killed = [_what(process) for process in stop_processes(self.processes, CLOSE_GRACE)]
        super().close()
        self.killed = killed + self.killed
        self.close_seconds = time.monotonic() - started

    # -- running things on a host ------------------------------------------------------------------------

    def nodes(self, model: str, *args: str, ready_timeout: float = READY_TIMEOUT,
              side: str = "robot1") -> NodeProcess:
        """``sm-bt sim-nodes MODEL ARGS`` on host ``side``, READY already seen."""
        process = HostNodeProcess(self, model, *args, ready_timeout=ready_timeout, side=side)
        process.start()
        self._check_exec(process)
        return process

    def manager(self, model: str, *args: str, wait: bool = True, side: str = BRAIN,
                ready_timeout: float = READY_TIMEOUT) -> ManagerProcess:
        """``python -m sm_bt.cli manager MODEL ARGS`` on host ``side``: serving already (``wait``, within
        ``ready_timeout`` s), or starting in the background (then call ``ready()`` on it)."""
        return super().manager(model, *args, wait=wait, side=side, ready_timeout=ready_timeout)

    def helper(self, name: str, *argv: str, side: str = BRAIN) -> Helper:
        """``ARGV`` on host ``side`` as a :class:`~hosts.Helper` (lines in, lines out), stopped at ``close()``."""
        helper = Helper(self.command(side, *argv), name)
        self.processes.append(helper.process)
        self._helpers.append(helper)
        return helper

    def robots_up(self, model: str = "pilot", *, state: str = "inactive", manager_args: tuple[str, ...] = (),
                  ready_timeout: float = 120.0) -> list[ManagerProcess]:
        """On every robot host ``robotK``: ``sm-bt sim-nodes MODEL --namespace /robotK --state STATE``, then
        ``sm-bt manager MODEL --namespace /robotK MANAGER_ARGS``, the robots all at once (each process may
        take ``ready_timeout`` s to start); the managers, serving, in the robots' order. A failure is raised
        once every start is over (``close()`` stops whatever did start)."""

        def robot(host: str) -> ManagerProcess:
            self.nodes(model, "--namespace", f"/{host}", "--state", state, ready_timeout=ready_timeout, side=host)
            return self.manager(model, "--namespace", f"/{host}", *manager_args, side=host,
                                ready_timeout=ready_timeout)

        with ThreadPoolExecutor(len(self.robots)) as pool:
            return list(pool.map(robot, self.robots))

    def ping(self, count: int = 20, interval: float = 0.05, wait: float = 2.0, side: str = "robot1",
             to: str | None = BRAIN) -> Ping:
        """ICMP echo from host ``side`` to host ``to``."""
        return super().ping(count, interval, wait, side=side, to=to)

    # -- the links ---------------------------------------------------------------------------------------

    def cut(self, side: str = BRAIN, how: str = "carrier") -> float:
        """Cut host ``side`` off the switch: the ``time.monotonic()`` of the cut.

        ``how="carrier"`` (the default) takes down its switch port, as a pulled cable: the host's veth stays
        up without carrier, its routes stay, and its processes still find each other. ``how="admin"``
        takes the host's own veth down, which also deletes its routes (see :meth:`hosts.Hosts.cut`).
        Cutting the brain cuts it off from every robot."""
        if how not in ("carrier", "admin"):
            raise ValueError(f"how={how!r}: carrier or admin")
        if side not in self.hosts:
            raise ValueError(f"side={side!r}: one of {', '.join(self.hosts)}")
        if how == "carrier":
            ip("-n", self.namespaces[SWITCH], "link", "set", self.ports[side], "down")
        else:
            ip("-n", self.namespaces[side], "link", "set", VETH, "down")
        self._down.add((side, how))
        return time.monotonic()

    def heal(self) -> float:
        """Plug back every host :meth:`cut` took off and route multicast there again: the
        ``time.monotonic()`` at which datagrams crossed again, from the brain to each host plugged back
        (to every robot if the brain was cut off), the latest of them. That is not when the links are up
        (see :meth:`hosts.Hosts.heal`): a probe sends a datagram every 10 ms from before."""
        healed = sorted({side for side, _ in self._down})
        targets = [host for host in healed if host != BRAIN] if BRAIN not in healed else list(self.robots)
        probes = [subprocess.Popen(["ip", "netns", "exec", self.namespaces[BRAIN], sys.executable, "-c", _ROUND_TRIP,
                                    self.addresses[target], str(HEAL_PROBE_TIMEOUT)],
                                   stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for target in targets]
        try:
            for probe in probes:
                assert probe.stdout is not None
                assert probe.stdout.readline().strip() == "READY", "a heal's probe did not start"
            for side, how in sorted(self._down):
                if how == "carrier":
                    ip("-n", self.namespaces[SWITCH], "link", "set", self.ports[side], "up")
                else:
                    ip("-n", self.namespaces[side], "link", "set", VETH, "up")
            for side in healed:
                self._route_multicast(side)
            self._down.clear()
            crossed = []
            for target, probe in zip(targets, probes, strict=True):
                out, err = probe.communicate(timeout=HEAL_PROBE_TIMEOUT + 10.0)
                assert probe.returncode == 0, (f"no datagram crossed to {target} within {HEAL_PROBE_TIMEOUT:g} s "
                                               f"of the heal: {err[-500:]}")
                crossed.append(float(out))
        finally:
            for probe in probes:
                if probe.poll() is None:
                    probe.kill()
                    probe.wait(5.0)
        return max(crossed, default=time.monotonic())

    def lossy(self, loss: float = 0.3, delay: float = 0.2) -> None:
        raise NotImplementedError("a fleet's switch is a kernel bridge: no loss or delay (hosts.Hosts has a relay)")

    def relay_stats(self) -> dict[str, int]:
        raise NotImplementedError("a fleet's switch is a kernel bridge: no relay to count frames")


@contextlib.contextmanager
def fleet_hosts(robots: int) -> Iterator[FleetHosts]:
    """A :class:`FleetHosts` of ``robots`` robots, open; closed at the end whatever happened (root needed:
    the test fails without it)."""
    require_root()
    hosts = FleetHosts(robots)
    try:
        hosts.open()
        yield hosts
    finally:
        hosts.close()

