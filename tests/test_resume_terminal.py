"""`./run_nodes.sh --resume` at a terminal lands on the review that was open (issue 59, item 2):
the launcher runs in a pseudo-terminal, as a person's shell runs it, so its human node is the
interactive terminal review. The person reviews the next episode, rejects its first plan and
stops the run with Ctrl-C; the resumed run shows that review's plan 2 and the prompt, without a
new `n` and without saying the episode "started"; its environment, killed then, returns to that
episode as well."""

from __future__ import annotations

import os
import pty
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest

pytest.importorskip("rclpy")
pytest.importorskip("lwm_interfaces")
from lwm_nodes import domains  # noqa: E402
from system_helpers import wait_for  # noqa: E402

pytestmark = pytest.mark.system

PROMPT = "answer: a approve"  # the first words of the terminal's prompt (terminal_reviewer.PROMPT)


class Terminal:
    """The launcher in a pseudo-terminal: what it prints is collected, what the test types goes in."""

    def __init__(self, cmd: list[str], env: dict, cwd: Path) -> None:
        master, slave = pty.openpty()
        self.proc = subprocess.Popen(cmd, stdin=slave, stdout=slave, stderr=slave, env=env, cwd=cwd)
        os.close(slave)
        self.master = master
        self.out = ""
        self.lock = threading.Lock()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        while True:
            try:
                data = os.read(self.master, 4096)
            except OSError:  # the terminal closed: every process on it ended
                return
            if not data:
                return
            with self.lock:
                self.out += data.decode(errors="replace")

    def text(self) -> str:
        with self.lock:
            return self.out

    def said(self, words: str, after: int = 0, timeout: float = 240) -> bool:
        return bool(wait_for(lambda: words in self.text()[after:], timeout=timeout))

    def type(self, line: str) -> None:
        os.write(self.master, (line + "\n").encode())

    def stop(self) -> int:
        """Ctrl-C, as the person stops the run; the launcher's exit status."""
        self.proc.send_signal(signal.SIGINT)
        try:
            return self.proc.wait(timeout=60)
        finally:
            os.close(self.master)


def terminal_env() -> dict:
    """A launcher's environment of its own: a free ROS domain, no run directory inherited."""
    env = {
        **os.environ,
        "ROS_DOMAIN_ID": str(domains.claim()),
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
        "PYTHONUNBUFFERED": "1",
    }
    env.pop("LWM_LOGS", None)
    env.pop("LWM_LEDGER", None)
    return env


def test_resume_lands_on_the_review_that_was_open(tmp_path):
    env = terminal_env()
    run = tmp_path / "run"
    cmd = [sys.executable, "-m", "lwm_nodes.launcher", "--quiet", "--iterations", "2", "--futures", "2"]

    first = Terminal([*cmd, "--log-dir", str(run)], env, tmp_path)
    try:
        assert first.said("=== plan 1 of review newall-test:0:0 "), first.text()[-3000:]
        assert first.said(PROMPT), first.text()[-3000:]
        first.type("n")
        assert first.said("episode newall-test:0:1 started"), first.text()[-3000:]
        assert first.said("=== plan 1 of review newall-test:0:1 "), first.text()[-3000:]
        first.type("r")
        assert first.said("=== plan 2 of review newall-test:0:1 "), first.text()[-3000:]
    finally:
        status = first.stop()
        (tmp_path / "first.txt").write_text(first.text())  # what the person saw, kept with the test
    assert status == 0, first.text()[-3000:]

    resumed = Terminal([*cmd, "--resume", str(run)], env, tmp_path)
    try:
        assert resumed.said("=== plan 2 of review newall-test:0:1 "), resumed.text()[-3000:]
        at = resumed.text().index("=== plan 2 of review newall-test:0:1 ")
        assert resumed.said(PROMPT, after=at), resumed.text()[-3000:]  # what to do next, after the plan
        said = resumed.text()
        assert "resuming the run in" in said
        assert "episode newall-test:0:1 started" not in said  # nothing was started: it was resumed
        assert "review newall-test:0:0" not in said.split("nodes ready", 1)[-1]  # not the earlier review
        # The environment killed now comes back to this episode too, not to the first seed's.
        found = subprocess.run(["pgrep", "-P", str(resumed.proc.pid), "-f", "lwm_nodes.env_node"], capture_output=True)
        os.kill(int(found.stdout.split()[0]), signal.SIGKILL)
        assert resumed.said("env exited with -9; restart 1", after=at), resumed.text()[-3000:]
        back = lambda: (run / "env.log").read_text().count("returns to episode newall-test:0:1") == 2  # noqa: E731
        assert wait_for(back, timeout=120), (run / "env.log").read_text()[-2000:]
    finally:
        status = resumed.stop()
        (tmp_path / "resumed.txt").write_text(resumed.text())
    assert status == 0, resumed.text()[-3000:]
    assert "review newall-test:0:1 resumed from the ledger at plan 2" in (run / "planner.log").read_text()
    # A game chosen beside --resume would silently lose to the saved episode: refused, saying why.
    both = subprocess.run([*cmd, "--resume", str(run), "--seed", "5"], env=env, cwd=tmp_path, capture_output=True,
                          text=True, timeout=60)  # fmt: skip
    assert both.returncode == 2 and "Traceback" not in both.stderr, both.stderr
    assert "--resume returns to the episode under review (newall-test:0:1); --seed would start another" in both.stderr
