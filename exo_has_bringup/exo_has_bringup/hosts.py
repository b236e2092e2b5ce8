"""Two hosts on one machine: network namespaces joined by a veth pair, with link faults.

The robot PC and the operator's laptop of a two-host session each get a network namespace of
their own, with only a loopback and one end of a veth pair on a private subnet, so that DDS
between them crosses a link as it would between two machines. (Shared memory is not a path
between them: Fast DDS tells hosts apart by their addresses and sends across by UDP, which
``test/test_two_hosts.py`` checks by cutting the link.) Faults are injected on that link: a
random loss share in each direction (``iptables -m statistic``, in each host's input chain,
for packets from the link only), and a partition (the link set down) that ends when it is set
up again.

A namespace is held by a process (``python -m exo_has_runtime.tether PID --netns new
exo_has_bringup.hosts``), tethered to the runner like every node: it has no name in
``/var/run/netns``, and when the runner ends, even by SIGKILL, its processes end and the
namespaces, the veth pair and the iptables rules with them. Nothing is left behind.

It needs root (CAP_SYS_ADMIN and CAP_NET_ADMIN), ``ip`` and ``nsenter``, and ``iptables`` for
losses; :class:`~exo_has_bringup.errors.HostsUnavailableError` says which is missing.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
from dataclasses import dataclass
from types import TracebackType

from exo_has_bringup.errors import HostsUnavailableError
from exo_has_runtime.processes import NodeProcess

#: The hosts of a two-host session and their addresses on the link (a private /24).
ROBOT, OPERATOR = 'robot', 'operator'
SUBNET_PREFIX = 24
ADDRESSES = {ROBOT: '10.77.0.1', OPERATOR: '10.77.0.2'}

#: Name of each host's end of the link, inside its namespace.
LINK_INTERFACE = 'link0'

#: What a holder prints once its namespace exists.
HOLDING = 'holding a network namespace'


def check_privileges(losses: bool = False) -> None:
    """Raise ``HostsUnavailableError`` unless network namespaces can be made here.

    Parameters
    ----------
    losses : bool
        Whether packet losses will be injected too (they need ``iptables``).

    """
    if os.geteuid() != 0:
        msg = ('two hosts need network namespaces, which need root (CAP_SYS_ADMIN and '
               'CAP_NET_ADMIN): run as root, or with sudo')
        raise HostsUnavailableError(msg)
    tools = ('ip', 'nsenter', *(('iptables',) if losses else ()))
    missing = [tool for tool in tools if shutil.which(tool) is None]
    if missing:
        packages = {'ip': 'iproute2', 'nsenter': 'util-linux', 'iptables': 'iptables'}
        msg = (f'two hosts need {", ".join(missing)}: install '
               f'{" ".join(packages[tool] for tool in missing)} (apt-get install ...)')
        raise HostsUnavailableError(msg)


@dataclass(frozen=True)
class Host:
    """One virtual host.

    Attributes
    ----------
    name : str
        ``robot`` or ``operator``.
    address : str
        Its IPv4 address on the link.
    netns : str
        Its network namespace (``/proc/<pid>/ns/net``), for :class:`NodeProcess`.

    """

    name: str
    address: str
    netns: str

    @property
    def environment(self) -> dict[str, str]:
        """The ROS discovery settings of this host's nodes, as on each of two machines.

        Multicast discovery on the link's subnet, and the other host as a static peer, so
        that the two find each other where a network does not carry multicast
        (bench/README.md, "Two hosts").
        """
        other = OPERATOR if self.name == ROBOT else ROBOT
        return {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET', 'ROS_STATIC_PEERS': ADDRESSES[other]}


class VirtualHosts:
    """The robot and the operator as two network namespaces joined by a link (a context manager).

    Raises
    ------
    HostsUnavailableError
        From :meth:`start`, where namespaces cannot be made.

    """

    def __init__(self) -> None:
        self.hosts: dict[str, Host] = {}
        self._holders: dict[str, NodeProcess] = {}
        self._loss = 0.0
        self._up = True

    def __enter__(self) -> VirtualHosts:
        self.start()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def start(self) -> None:
        """Make the two namespaces and the link between them, up, without loss."""
        check_privileges()
        # Unique in this namespace only while both ends are here, before they move.
        ends = {host: f'exo{os.getpid() % 100000}{host[0]}' for host in (ROBOT, OPERATOR)}
        try:
            for name in (ROBOT, OPERATOR):
                holder = NodeProcess('exo_has_bringup.hosts', (), netns='new')
                self._holders[name] = holder
                holder.wait_for_output(HOLDING, timeout_s=10.0)
                self.hosts[name] = Host(name, ADDRESSES[name],
                                        f'/proc/{holder.process.pid}/ns/net')
            _run('ip', 'link', 'add', ends[ROBOT], 'type', 'veth', 'peer', 'name',
                 ends[OPERATOR])
            for name, host in self.hosts.items():
                pid = self._holders[name].process.pid
                _run('ip', 'link', 'set', ends[name], 'netns', str(pid))
                self.inside(name, 'ip', 'link', 'set', ends[name], 'name', LINK_INTERFACE)
                self.inside(name, 'ip', 'address', 'add', f'{host.address}/{SUBNET_PREFIX}',
                            'dev', LINK_INTERFACE)
                self.inside(name, 'ip', 'link', 'set', 'lo', 'up')
                self.inside(name, 'ip', 'link', 'set', LINK_INTERFACE, 'up')
        except BaseException:
            self.close()
            raise

    def inside(self, host: str, *command: str) -> str:
        """Run a command in a host's namespace; return its output.

        Raises
        ------
        HostsUnavailableError
            If it fails; the message quotes the command and its error.

        """
        return _run('nsenter', f'--net={self.hosts[host].netns}', *command)

    def set_loss(self, share: float) -> None:
        """Drop ``share`` (0 to 1) of the packets crossing the link, in each direction at random.

        Raises
        ------
        ValueError
            If the share is not within [0, 1].

        """
        if not 0.0 <= share <= 1.0:
            msg = f'loss share {share!r} must be within [0, 1]'
            raise ValueError(msg)
        check_privileges(losses=True)
        for name in self.hosts:
            self.inside(name, 'iptables', '-F', 'INPUT')
            if share > 0.0:
                self.inside(name, 'iptables', '-A', 'INPUT', '-i', LINK_INTERFACE, '-m',
                            'statistic', '--mode', 'random', '--probability', f'{share:.6f}',
                            '-j', 'DROP')
        self._loss = share

    @property
    def loss(self) -> float:
        """The share of packets dropped in each direction."""
        return self._loss

    @property
    def link_up(self) -> bool:
        """Whether the link is up (no partition)."""
        return self._up

    def cut(self) -> None:
        """Partition the hosts: set the link down (on both ends, as a pulled cable does)."""
        for name in self.hosts:
            self.inside(name, 'ip', 'link', 'set', LINK_INTERFACE, 'down')
        self._up = False

    def restore(self) -> None:
        """End a partition: the link up again (addresses and routes come back with it)."""
        for name in self.hosts:
            self.inside(name, 'ip', 'link', 'set', LINK_INTERFACE, 'up')
        self._up = True

    def close(self) -> None:
        """End the holders: the namespaces, the link and its rules go once their nodes ended."""
        for holder in self._holders.values():
            holder.stop(timeout_s=2.0)
        self._holders.clear()
        self.hosts.clear()


def _run(*command: str) -> str:
    try:
        done = subprocess.run(command, capture_output=True, text=True, check=False,
                              timeout=10.0)
    except (OSError, subprocess.TimeoutExpired) as exc:
        msg = f'{" ".join(command)}: {exc}'
        raise HostsUnavailableError(msg) from None
    if done.returncode != 0:
        msg = f'{" ".join(command)} failed: {done.stderr.strip() or done.returncode}'
        raise HostsUnavailableError(msg)
    return done.stdout


def main() -> None:
    """Hold this process's network namespace until SIGINT or SIGTERM."""
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    print(HOLDING, flush=True)
    try:
        while True:
            signal.pause()
    except KeyboardInterrupt:
        pass


if __name__ == '__main__':
    main()
