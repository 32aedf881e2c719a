"""What the tests of whole ROS systems share: waiting for a condition, finding a node's process in
a test's own ROS domain, and starting the launcher with the scripted reviewer."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

from lwm_nodes import domains


def wait_for(predicate, timeout: float = 15.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.3)
    return predicate()


def node_pid(module: str, domain: str) -> int:
    """The pid of a node process of the given ROS domain (other tests' systems may be running)."""
    for pid in subprocess.run(["pgrep", "-f", module], capture_output=True, text=True).stdout.split():
        try:
            environ = Path(f"/proc/{pid}/environ").read_bytes().split(b"\0")
        except OSError:
            continue
        if f"ROS_DOMAIN_ID={domain}".encode() in environ:
            return int(pid)
    raise AssertionError(f"no {module} process in domain {domain}")


def start_scripted(tmp_path: Path, *extra: str) -> tuple[subprocess.Popen, dict, Path]:
    """The launcher with the scripted human, in its own ROS domain; returns (process, env, ledger)."""
    env = {
        **os.environ,
        "ROS_DOMAIN_ID": str(domains.claim()),
        "ROS_LOG_DIR": str(tmp_path / "roslog"),
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
    }
    ledger = tmp_path / "ledger.sqlite"
    cmd = [
        sys.executable,
        "-m",
        "lwm_nodes.launcher",
        "--scripted",
        "--quiet",
        "--log-dir",
        str(tmp_path / "logs"),
        "--ledger",
        str(ledger),
        "--iterations",
        "4",
        "--futures",
        "4",
        # The agent's self-taught plan may be approved at once; these tests need the teaching rounds.
        "--approve-return",
        "2",
        *extra,
    ]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    return proc, env, ledger
