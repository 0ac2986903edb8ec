"""Linux network namespaces as test hosts: two namespaces joined by a veth pair.

Addresses of our own (10.200.<k>.1/30 and .2/30, inside the namespaces only; nothing outside
is touched), the link shaped to 50 Mbit/s (tc tbf) so the tests' traffic is bounded. Used by
the multi-host test and the network-boundary test.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys

__all__ = ['Hosts', 'cannot_create_namespaces', 'ip']


def ip(*args: str, check: bool = True) -> subprocess.CompletedProcess[str]:
    return subprocess.run(['ip', *args], capture_output=True, text=True, timeout=20,
                          check=check)


class Hosts:
    """Two network namespaces joined by a veth pair; removed by ``close``."""

    def __init__(self) -> None:
        k = os.getpid() % 250 + 1
        self.names = (f'galvo_host_a_{os.getpid()}', f'galvo_host_b_{os.getpid()}')
        self.links = (f'gva{os.getpid() % 100000}', f'gvb{os.getpid() % 100000}')
        self.addresses = (f'10.200.{k}.1', f'10.200.{k}.2')
        self.created: list[str] = []

    def create(self) -> None:
        for ns in self.names:
            ip('netns', 'add', ns)
            self.created.append(ns)
        a, b = self.links
        ip('link', 'add', a, 'type', 'veth', 'peer', 'name', b)
        for ns, link, addr in zip(self.names, self.links, self.addresses, strict=True):
            ip('link', 'set', link, 'netns', ns)
            ip('-n', ns, 'addr', 'add', f'{addr}/30', 'dev', link)
            ip('-n', ns, 'link', 'set', 'lo', 'up')
            ip('-n', ns, 'link', 'set', link, 'up')
            # bounded traffic: shape the link (tc is optional; without it the test still runs)
            if shutil.which('tc'):
                subprocess.run(['ip', 'netns', 'exec', ns, 'tc', 'qdisc', 'add', 'dev', link,
                                'root', 'tbf', 'rate', '50mbit', 'burst', '256kb',
                                'latency', '200ms'], capture_output=True, timeout=20,
                               check=False)

    def tx_bytes(self, which: int) -> int:
        out = ip('-n', self.names[which], '-s', 'link', 'show', self.links[which]).stdout
        lines = out.splitlines()
        i = next(j for j, line in enumerate(lines) if line.strip().startswith('TX:'))
        return int(lines[i + 1].split()[0])

    def close(self) -> None:
        for ns in self.created:
            ip('netns', 'del', ns, check=False)


def cannot_create_namespaces() -> str | None:
    if sys.platform != 'linux':
        return 'network namespaces are Linux only'
    if os.geteuid() != 0:
        return 'creating network namespaces needs root (CAP_NET_ADMIN)'
    if shutil.which('ip') is None:
        return "the 'ip' command (iproute2) is not installed"
    probe = f'galvo_probe_{os.getpid()}'
    result = ip('netns', 'add', probe, check=False)
    if result.returncode != 0:
        return f'ip netns add failed: {result.stderr.strip()}'
    ip('netns', 'del', probe, check=False)
    return None
