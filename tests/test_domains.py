"""ROS domains for tests and benchmarks: an id one process claims is refused to every other until
that process ends, however it ends."""

from __future__ import annotations

import os
import signal
import subprocess
import sys

from lwm_nodes import domains

CLAIM = "from lwm_nodes import domains; import sys, time; print(domains.claim(), flush=True); time.sleep(60)"


def test_a_domain_held_by_one_process_is_never_given_to_another_until_it_dies(tmp_path, monkeypatch):
    # A lock directory of its own: the ids this test process holds for other tests stay held.
    env = {**os.environ, "LWM_DOMAIN_LOCK_DIR": str(tmp_path)}
    monkeypatch.setenv("LWM_DOMAIN_LOCK_DIR", str(tmp_path))
    monkeypatch.setattr(domains, "_held", {})
    try:
        holder = subprocess.Popen([sys.executable, "-c", CLAIM], env=env, stdout=subprocess.PIPE, text=True)
        held = int(holder.stdout.readline())
        assert domains.FIRST <= held <= domains.LAST and domains.is_held_elsewhere(held)
        mine = {domains.claim() for _ in range(domains.LAST - domains.FIRST)}  # every other id
        assert held not in mine and len(mine) == domains.LAST - domains.FIRST
        holder.send_signal(signal.SIGKILL)  # a crashed run: the kernel drops its lock
        holder.wait(10)
        assert not domains.is_held_elsewhere(held) and domains.claim() == held
    finally:
        for domain in list(domains._held):
            domains.release(domain)
