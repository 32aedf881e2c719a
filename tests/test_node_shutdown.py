"""A node process ends within 2 s of SIGTERM even when its teardown stalls (issue 12: a node was
still there 10 s after SIGTERM, now and then). Real rclpy processes; the stall is injected into
the node's close(): one that releases the GIL (a sleep) and one that holds it (a regular
expression that backtracks for minutes, which CPython runs without releasing the GIL)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time

import pytest

pytest.importorskip("rclpy")
from lwm_nodes import domains  # noqa: E402

NODE = textwrap.dedent(
    """
    import re, sys, time
    from lwm_nodes.common import JsonNode, run

    STALL = sys.argv[1]

    class Stalling(JsonNode):
        def close(self):
            if STALL == "sleep":
                time.sleep(60)
            elif STALL == "gil":
                re.match(r"(a+)+$", "a" * 40 + "b")

    run(lambda: Stalling("stalling_node"))
    """
)


def stop_and_time(stall: str, tmp_path) -> tuple[int, float, str]:
    env = {
        **os.environ,
        "ROS_DOMAIN_ID": str(domains.claim()),
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
        "ROS_LOG_DIR": str(tmp_path / "roslog"),
        "PYTHONUNBUFFERED": "1",
    }
    proc = subprocess.Popen(
        [sys.executable, "-c", NODE, stall], env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    try:
        line = proc.stdout.readline()
        assert line.startswith("READY stalling_node"), line
        time.sleep(0.5)
        sent = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(timeout=10)
        took = time.monotonic() - sent
        return code, took, proc.stdout.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_a_clean_teardown_exits_0_at_once(tmp_path):
    code, took, out = stop_and_time("none", tmp_path)
    assert code == 0 and took < 2.0, (code, took, out)
    assert "stopped in" in out and "stop deadline" not in out, out


def test_a_teardown_that_stalls_ends_by_the_deadline_and_names_the_phase(tmp_path):
    code, took, out = stop_and_time("sleep", tmp_path)
    assert code == 0 and took < 2.0, (code, took, out)
    assert "stop deadline: teardown stalled after 'start'" in out, out


def test_a_teardown_that_holds_the_gil_ends_by_the_deadline_with_its_stack_in_the_log(tmp_path):
    # Exit code 0, the run's: a stall in teardown must not make ./run_nodes.sh report a failure.
    code, took, out = stop_and_time("gil", tmp_path)
    assert code == 0 and took < 2.5, (code, took, out)
    assert "Timeout" in out and "in close" in out, out


def test_the_exit_timer_ends_a_process_that_holds_the_gil_with_the_given_code():
    held = textwrap.dedent(
        """
        import ctypes
        from lwm_nodes.common import exit_timer

        assert exit_timer(0.3, 7)
        ctypes.PyDLL(None).sleep(20)  # a C call made with the GIL held: no Python thread can run
        print("the timer did not fire")
        """
    )
    proc = subprocess.run([sys.executable, "-c", held], capture_output=True, text=True, timeout=15)
    assert proc.returncode == 7, (proc.returncode, proc.stdout, proc.stderr)
    assert "did not fire" not in proc.stdout
