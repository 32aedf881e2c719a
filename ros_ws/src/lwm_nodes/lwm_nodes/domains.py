"""ROS_DOMAIN_IDs that no other process on this machine holds, for tests and benchmarks.

Two test runs (or a test run and a benchmark) on one machine must never see each other's nodes.
A domain derived from a pid collides now and then (`1 + pid % 100` did). Here each id is claimed
with an exclusive flock on a file of its own: the kernel drops the claim when the holding process
ends, however it ends, so a crashed run leaves nothing to clean up. Importing this module does
not import rclpy.
"""

from __future__ import annotations

import fcntl
import os
import random
import tempfile
from pathlib import Path

# Fast DDS maps domain d to UDP ports 7400 + 250 d + ...; 1-101 keeps them below the ephemeral
# range on Linux. 0 is left to the user's own system (ROS's default).
FIRST, LAST = 1, 101
_held: dict[int, int] = {}  # domain -> the open file descriptor that holds its lock


def lock_dir() -> Path:
    path = Path(os.environ.get("LWM_DOMAIN_LOCK_DIR") or Path(tempfile.gettempdir()) / "lwm-ros-domains")
    path.mkdir(parents=True, exist_ok=True)
    return path


def claim() -> int:
    """A domain id that this process now holds until it exits (or `release`). Tries the ids in a
    random order, so that concurrent claimers rarely contend for the same file."""
    ids = list(range(FIRST, LAST + 1))
    random.SystemRandom().shuffle(ids)
    for domain in ids:
        if domain in _held:
            continue
        fd = os.open(lock_dir() / f"{domain}.lock", os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            continue
        _held[domain] = fd
        return domain
    raise RuntimeError(f"every ROS domain {FIRST}-{LAST} is held by another process on this machine")


def release(domain: int) -> None:
    fd = _held.pop(domain, None)
    if fd is not None:
        os.close(fd)  # closing the descriptor drops its lock


def is_held_elsewhere(domain: int) -> bool:
    """True when another process holds `domain` (for tests of the allocator)."""
    if domain in _held:
        return False
    fd = os.open(lock_dir() / f"{domain}.lock", os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    finally:
        os.close(fd)
    return False


__all__ = ["claim", "is_held_elsewhere", "release"]
