"""Two network namespaces joined by a veth pair: two "hosts" on one machine (Linux, root).

Used by the two-host test and benchmarks (docs/two-hosts.md): processes started with
:meth:`NetworkNamespace.exec_prefix` see only loopback and their end of the link, so DDS
traffic between the namespaces crosses the link over UDP and nothing leaves the machine.
Addresses come from the documentation range 192.0.2.0/24 (RFC 5737).
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

from tlessbot_ros.errors import TlessbotError

SUBNET_PREFIX = '192.0.2.'
PREFIX_LENGTH = 24
IP_TIMEOUT_S = 10.0
# Fast DDS discovery goes to multicast 239.255.0.1; a namespace without a default route needs
# this route to send it out of the link (a real host's default route does the same).
MULTICAST_ROUTE = '224.0.0.0/4'
UDP_PROFILE_NAME = 'fastdds_udp.xml'


@dataclass(frozen=True)
class NetworkNamespace:
    """A namespace and its end of the link: name, interface, IPv4 address."""

    name: str
    interface: str
    address: str

    def exec_prefix(self) -> list[str]:
        """The argv prefix that runs a command inside this namespace."""
        return ['ip', 'netns', 'exec', self.name]


def _ip(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    result = subprocess.run(['ip', *args], capture_output=True, text=True,
                            timeout=IP_TIMEOUT_S)
    if check and result.returncode != 0:
        raise TlessbotError(f'ip {" ".join(args)} failed: {result.stderr.strip()}')
    return result


def received_bytes(namespace: NetworkNamespace) -> int:
    """Bytes the namespace's end of the link has received so far."""
    result = _ip('-n', namespace.name, '-j', '-s', 'link', 'show', 'dev', namespace.interface)
    return int(json.loads(result.stdout)[0]['stats64']['rx']['bytes'])


def netns_unavailable() -> str | None:
    """Why two namespaces cannot be made here (not root, no ``ip``), or None."""
    if shutil.which('ip') is None:
        return 'the ip command (iproute2) is not installed'
    if os.geteuid() != 0:
        return 'creating network namespaces needs root'
    return None


@contextmanager
def two_namespaces(tag: str = 'tlessbot') -> Iterator[tuple[NetworkNamespace, NetworkNamespace]]:
    """Create namespaces ``<tag>-<pid>-a`` / ``-b`` joined by a veth pair (192.0.2.1 and .2,
    loopback up in both); delete them on exit, also after an error. Interfaces are made
    inside the namespaces, never in the caller's."""
    reason = netns_unavailable()
    if reason is not None:
        raise TlessbotError(f'cannot create network namespaces: {reason}')
    pid = os.getpid()
    ends = [NetworkNamespace(f'{tag}-{pid}-{side}', f'tlv{pid % 10**8}{side}',
                             f'{SUBNET_PREFIX}{index}')
            for index, side in enumerate('ab', start=1)]
    created: list[str] = []
    try:
        for end in ends:
            _ip('netns', 'add', end.name)
            created.append(end.name)
        a, b = ends
        _ip('link', 'add', a.interface, 'netns', a.name, 'type', 'veth',
            'peer', 'name', b.interface, 'netns', b.name)
        for end in ends:
            _ip('-n', end.name, 'addr', 'add', f'{end.address}/{PREFIX_LENGTH}',
                'dev', end.interface)
            _ip('-n', end.name, 'link', 'set', 'lo', 'up')
            _ip('-n', end.name, 'link', 'set', end.interface, 'up')
            _ip('-n', end.name, 'route', 'add', MULTICAST_ROUTE, 'dev', end.interface)
        yield a, b
    finally:
        for name in created:   # the veth pair goes with its namespaces
            _ip('netns', 'delete', name, check=False)


def udp_environ(base: dict[str, str], peers: list[str], *,
                profile: str | None = None) -> dict[str, str]:
    """``base`` set up for a graph across hosts: the UDP profile (``profile`` or the package's
    config/fastdds_udp.xml), discovery over the subnet and the ``peers``' addresses as static
    peers (unicast discovery, for networks that drop multicast)."""
    from tlessbot_ros.io.config import package_path
    from tlessbot_ros.nodes.common import DDS_PROFILE_VARIABLES

    path = profile or str(package_path('config', UDP_PROFILE_NAME))
    environ = dict(base, ROS_AUTOMATIC_DISCOVERY_RANGE='SUBNET',
                   ROS_STATIC_PEERS=';'.join(peers))
    environ.update(dict.fromkeys(DDS_PROFILE_VARIABLES, path))
    return environ
