"""A terminal review as a person types it (issue 59, items 4 and 7): the launcher runs in a
pseudo-terminal, its human node is the interactive review. The person corrects a step, takes the
correction back, sends a manual of their own, takes that back too, and approves: the report then
shows the real episode beside the imagined one, how it ended, and what to do next; `f` shows every
step."""

from __future__ import annotations

import sys

import pytest

pytest.importorskip("rclpy")
pytest.importorskip("lwm_interfaces")
from test_resume_terminal import PROMPT, Terminal, terminal_env  # noqa: E402

from lwm_models.data.splits import load_split  # noqa: E402

pytestmark = pytest.mark.system

WORDS = {"enemy": "is deadly: stay away from it", "message": "carries the secret message",
         "goal": "is where the message must be brought"}  # fmt: skip


def test_a_terminal_session_with_undo_and_the_report(tmp_path):
    game = load_split("newall-test")[0]
    mine = [f"the {e.identity} {WORDS[e.role]}" for e in game.entities]
    env = terminal_env()
    cmd = [sys.executable, "-m", "lwm_nodes.launcher", "--iterations", "1", "--futures", "2"]
    term = Terminal([*cmd, "--log-dir", str(tmp_path / "run")], env, tmp_path)
    review = "review newall-test:0:0"

    def step(line: str, *expected: str) -> int:
        at = len(term.text())
        term.type(line)
        for words in expected:
            assert term.said(words, after=at), f"after {line!r}, no {words!r} in:\n" + term.text()[at:][-4000:]
        return at

    try:
        assert term.said(f"=== plan 1 of {review} "), term.text()[-3000:]
        assert term.said(PROMPT), term.text()[-3000:]
        step("u", "not sent: nothing to take back")  # nothing of the person's is in force yet
        step("c 1:stay", "corrections of plan 1 taken", f"=== plan 2 of {review} (corrections)")
        step("undo", "your corrections (on plan 1) taken back", f"=== plan 3 of {review} (undo)")
        at = step("m", "three descriptions, one per line:")
        for line in mine:
            term.type(line)
        assert term.said(f"=== plan 4 of {review} (manual), manual v2", after=at), term.text()[at:][-3000:]
        at = step("u", "world-model server: manual version 3 taken", f"=== plan 5 of {review} (manual), manual v3")
        assert mine[0] not in term.text()[at:].split("=== plan 5", 1)[1]  # the manual before it, again
        at = step("a", "plan 5 approved", f"=== report of {review}: plan 5", "real steps: ", "what next: n the next")
        report = term.text()[at:]
        assert "real" in report and "imagined (plan 5)" in report and "+---" in report
        assert any(f"the agent {end}" in report for end in ("died at step", "won at step", "ran out of time"))
        at = step("f", "what next: n the next")
        every = term.text()[at:]
        steps = int(report.split(" steps, ")[0].rsplit(" ", 1)[-1]) if " steps, " in report else None
        assert every.count("imagined (plan 5)") >= 3 and (
            steps is None or every.count("imagined (plan 5)") == steps + 1
        )
    finally:
        status = term.stop()
        (tmp_path / "terminal.txt").write_text(term.text())  # what the person saw, kept with the test
    assert status == 0, term.text()[-3000:]
