"""Two simulated hosts on this machine: network namespaces joined by a veth pair, with multicast
routed on it so that DDS discovery reaches across (traffic stays on the machine). For the
across-hosts test and benchmarks/fleet.py; needs root and `ip netns`.

Processes in them must hold Fast DDS to UDP (HOST_ENV), or they would meet through shared memory
whatever the network says."""

from __future__ import annotations

import os
import shutil
import subprocess
from collections.abc import Iterator
from contextlib import contextmanager

# What a node of a simulated host needs: discovery beyond the local host, and UDP only.
HOST_ENV = {"ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET", "FASTDDS_BUILTIN_TRANSPORTS": "UDPv4"}


def ip(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["ip", *args], capture_output=True, text=True)


def unavailable() -> str | None:
    """Why namespaces cannot be made here, or None when they can."""
    if shutil.which("ip") is None:
        return "the ip command (iproute2) is not installed"
    if os.geteuid() != 0:
        return "creating network namespaces needs root"
    probe = f"lwmprobe{os.getpid() % 100000}"
    made = ip("netns", "add", probe)
    if made.returncode != 0:
        return f"ip netns add failed: {made.stderr.strip()}"
    ip("netns", "del", probe)
    return None


@contextmanager
def two_hosts() -> Iterator[tuple[str, str]]:
    """Namespaces A (10.77.N.1) and B (10.77.N.2) on one veth pair, multicast routed on it;
    removed on exit. Yields their names, for `ip netns exec NAME ...` (see `in_host`)."""
    n = os.getpid() % 200 + 1
    a, b, va, vb = f"lwmA{n}", f"lwmB{n}", f"lwva{n}", f"lwvb{n}"
    steps = [
        ("netns", "add", a),
        ("netns", "add", b),
        ("link", "add", va, "type", "veth", "peer", "name", vb),
        ("link", "set", va, "netns", a),
        ("link", "set", vb, "netns", b),
    ]
    for ns, dev, addr in ((a, va, f"10.77.{n}.1/24"), (b, vb, f"10.77.{n}.2/24")):
        steps += [
            ("-n", ns, "addr", "add", addr, "dev", dev),
            ("-n", ns, "link", "set", dev, "multicast", "on"),
            ("-n", ns, "link", "set", dev, "up"),
            ("-n", ns, "link", "set", "lo", "up"),
            ("-n", ns, "route", "add", "224.0.0.0/4", "dev", dev),
        ]
    try:
        for step in steps:
            done = ip(*step)
            if done.returncode != 0:
                raise RuntimeError(f"ip {' '.join(step)}: {done.stderr.strip()}")
        yield a, b
    finally:
        ip("netns", "del", a)
        ip("netns", "del", b)


def in_host(ns: str, command: list[str]) -> list[str]:
    """`command` run inside namespace `ns`."""
    return ["ip", "netns", "exec", ns, *command]


__all__ = ["HOST_ENV", "in_host", "ip", "two_hosts", "unavailable"]
